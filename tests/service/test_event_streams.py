"""Event streams (``GET /v1/jobs/{id}/events``, :mod:`service.routes.events`): capped per
tenant, ended after their lifetime, and polling less while idle."""

from __future__ import annotations

import asyncio
import types
from typing import Any

import pytest

from service.deps import AppState
from service.routes import events as events_route
from tests.service.conftest import (
    AUTH_A,
    TestClient,
    state_of,
)


def queued_job(client: TestClient, upload_id: str) -> str:
    response = client.post("/v1/jobs", json={"upload_id": upload_id}, headers=AUTH_A)
    assert response.status_code == 202, response.text
    job_id: str = response.json()["id"]
    return job_id


class FakeTime:
    """A clock that only moves when the stream sleeps; stops the stream after ``limit_s``."""

    def __init__(self, limit_s: float) -> None:
        self.now = 0.0
        self.limit_s = limit_s

    def monotonic(self) -> float:
        return self.now

    async def sleep(self, seconds: float) -> None:
        self.now += seconds
        if self.now > self.limit_s:
            raise TimeoutError(f"the stream was still open after {self.limit_s} s")


def run_stream(
    monkeypatch: pytest.MonkeyPatch, state: AppState, job_id: str, fake: FakeTime
) -> tuple[list[str], dict[str, int]]:
    """Drive the event stream of ``job_id`` on ``fake`` time; returns its chunks and the number
    of store calls it made (``events_after`` and ``get_job``)."""
    calls = {"events_after": 0, "get_job": 0}
    for name in calls:
        original = getattr(state.store, name)

        def counted(*args: Any, _name: str = name, _original: Any = original) -> Any:
            calls[_name] += 1
            return _original(*args)

        monkeypatch.setattr(state.store, name, counted)
    monkeypatch.setattr(events_route, "asyncio", types.SimpleNamespace(sleep=fake.sleep))
    monkeypatch.setattr(events_route, "time", types.SimpleNamespace(monotonic=fake.monotonic))

    async def collect() -> list[str]:
        chunks: list[str] = []
        try:
            async for chunk in events_route.stream_events(state, job_id, 0):
                chunks.append(chunk)
        except TimeoutError:
            pass
        return chunks

    return asyncio.run(collect()), calls


def test_idle_stream_backs_off_polling(client, upload_id, monkeypatch):
    """ "each stream polls the database twice a second": an idle stream backs off to
    ``stream_poll_max_s`` and checks the job itself only with each keep-alive."""
    state = state_of(client)
    job_id = queued_job(client, upload_id)
    state.settings = state.settings.model_copy(
        update={"poll_interval_s": 0.5, "stream_poll_max_s": 5.0, "max_stream_s": 10_000.0}
    )
    duration = 600.0
    _, calls = run_stream(monkeypatch, state, job_id, FakeTime(duration))
    polls = duration / 5.0 + 10
    assert calls["events_after"] <= polls
    assert calls["get_job"] <= duration / events_route.KEEPALIVE_S + 1
    assert calls["events_after"] >= duration / 5.0 - 10  # still polling, just slower


def test_stream_ends_after_its_lifetime(client, upload_id, monkeypatch):
    """ "no ... lifetime": the stream ends cleanly after ``max_stream_s``; clients reconnect with
    ``Last-Event-ID`` and miss nothing."""
    state = state_of(client)
    job_id = queued_job(client, upload_id)
    state.settings = state.settings.model_copy(update={"max_stream_s": 120.0})
    chunks, _ = run_stream(monkeypatch, state, job_id, FakeTime(3600.0))
    sent = [chunk.split("\n")[0] for chunk in chunks if chunk.startswith("id: ")]
    assert sent, "the queued job's status event"
    last_id = sent[-1].removeprefix("id: ")
    assert chunks[-1] == f": stream lifetime reached; reconnect with Last-Event-ID: {last_id}\n\n"
    assert not any("event: completed" in chunk for chunk in chunks)


def test_event_streams_capped_per_tenant(tmp_path, upload_id, client):
    """ "SSE: no per-tenant stream cap": one stream over ``max_streams_per_tenant`` is 429."""
    state = state_of(client)
    job_id = queued_job(client, upload_id)
    state.settings = state.settings.model_copy(update={"max_streams_per_tenant": 1})
    url = f"/v1/jobs/{job_id}/events"
    with client.stream("GET", url, headers=AUTH_A) as first:
        assert first.status_code == 200
        assert next(first.iter_lines()) == "retry: 2000"
        with client.stream("GET", url, headers=AUTH_A) as second:
            assert second.status_code == 429
            assert "DCSEG_MAX_STREAMS_PER_TENANT" in second.read().decode()
            assert int(second.headers["retry-after"]) >= 1
    assert state.streams.open("tenant-a") == 0  # the client went away: its slot is free
