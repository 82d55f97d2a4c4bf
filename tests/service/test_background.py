"""Background tasks' blocking calls finish before a cancellation ends the task, so the app's
shutdown never closes the store under a sweep that still holds a database connection."""

from __future__ import annotations

import asyncio
import threading
import time
from typing import Any

import pytest

from jobstore.store import Store
from service import main
from service.background import in_thread
from service.main import create_app
from tests.service.conftest import TestClient, make_settings


def test_a_cancelled_caller_waits_for_its_thread_to_return():
    returned = threading.Event()

    def slow() -> int:
        time.sleep(0.3)
        returned.set()
        return 1

    async def scenario() -> None:
        task = asyncio.ensure_future(in_thread(slow))
        await asyncio.sleep(0.05)  # the thread is running
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task
        assert returned.is_set()  # run_in_threadpool alone ends the task before this

    asyncio.run(scenario())


def test_results_and_errors_pass_through():
    def fail() -> None:
        raise ValueError("boom")

    assert asyncio.run(in_thread(divmod, 7, 2)) == (3, 1)
    with pytest.raises(ValueError, match="boom"):
        asyncio.run(in_thread(fail))


def test_shutdown_closes_the_store_after_the_recovery_sweep_returns(tmp_path, monkeypatch):
    """Found by CI: a psycopg connection of a sweep cancelled mid-call was returned to the
    disposed pool, never closed, and warned when garbage-collected."""
    order: list[str] = []
    sweeping = threading.Event()

    def slow_sweep(*_args: Any) -> None:
        sweeping.set()
        time.sleep(0.5)
        order.append("sweep returned")

    real_close = Store.close

    def close(self: Store) -> None:
        order.append("store closed")
        real_close(self)

    monkeypatch.setattr(main, "recover_once", slow_sweep)
    monkeypatch.setattr(Store, "close", close)
    settings = make_settings(tmp_path, sweep_interval_s=0.05)
    with TestClient(create_app(settings)):
        assert sweeping.wait(10)
    assert order == ["sweep returned", "store closed"]
