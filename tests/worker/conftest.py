"""Fixtures of the worker tests: a store with one tenant, one upload and helpers to add jobs."""

from __future__ import annotations

import signal
import subprocess
import sys
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any

import pytest
from pydantic import SecretStr

from jobstore.models import Job, Upload
from jobstore.settings import Settings
from jobstore.store import Store, new_id
from tests.service.conftest import (
    scene,  # noqa: F401 (the shared synthetic capture fixture)
    stop_process,
)

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture
def settings(tmp_path: Path) -> Settings:
    return Settings(
        storage_dir=tmp_path / "data",
        database_url=None,
        broker_url=None,
        api_keys=SecretStr(""),
        heartbeat_s=0.1,
        poll_interval_s=0.05,
    )


@pytest.fixture
def store(settings: Settings) -> Iterator[Store]:
    settings.storage_dir.mkdir(parents=True)
    store = Store(settings.db_url)
    store.init_schema()
    store.ensure_tenant("t")
    upload = Upload(id="u1", tenant_id="t", sha256="0" * 64, size=1, content_type="x", summary={})
    store.add_upload(upload)
    (settings.storage_dir / "uploads" / "u1" / "data").mkdir(parents=True)
    yield store
    store.close()


def add_job(store: Store, parent: str | None = None, options: dict[str, Any] | None = None) -> str:
    job = Job(
        id=new_id(),
        tenant_id="t",
        upload_id="u1",
        parent_job_id=parent,
        status="queued",
        config={"preset": "fast", "options": options or {}},
        event_seq=0,
    )
    return store.create_job(job).id


@contextmanager
def worker_processes(
    env: Mapping[str, str], logs: Path
) -> Iterator[Callable[[], subprocess.Popen[bytes]]]:
    """A starter of real ``dcseg worker --pool solo`` processes with ``env``, each logging to
    ``logs/worker<i>.log``; every process still running is stopped (SIGTERM) on exit."""
    started: list[tuple[subprocess.Popen[bytes], IO[bytes]]] = []

    def start() -> subprocess.Popen[bytes]:
        log = (logs / f"worker{len(started)}.log").open("wb")
        command = [sys.executable, "-m", "dcseg", "worker", "--pool", "solo", "--loglevel", "info"]
        process = subprocess.Popen(
            command, env=dict(env), cwd=REPO, stdout=log, stderr=subprocess.STDOUT
        )
        started.append((process, log))
        return process

    try:
        yield start
    finally:
        for process, log in started:
            if process.poll() is None:
                stop_process(process, signal.SIGTERM, 15)
            log.close()


def worker_log(logs: Path, tail: int = 4000) -> str:
    """The last ``tail`` characters of every worker log in ``logs`` (0 = all of it)."""
    return "\n".join(p.read_text(errors="replace")[-tail:] for p in logs.glob("worker*.log"))
