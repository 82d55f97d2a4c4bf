"""``dcseg.client.AsyncClient`` against a real server with injected faults: the retry policy it
shares with the blocking client, resumable downloads, and the event stream."""

from __future__ import annotations

import asyncio
import os
import threading
from typing import Any

import pytest

from dcseg.client import ApiError, AsyncClient, JobFailed, RetryPolicy, ServerEvent
from tests.service.conftest import KEY_A, tar_bytes
from tests.service.live import (
    Fault,
    LiveServer,
    execute,
    finished_job,
    live,
    queued_job,
    run_stages,
)
from tests.worker.fakes import FakeStage

__all__ = ["live"]

PAYLOAD = os.urandom(2 << 20)
NAME = "segment/scene_labelled.ply"
FAST = RetryPolicy(backoff_s=0.05, max_backoff_s=0.1)


@pytest.fixture
def live_overrides() -> dict[str, Any]:
    return {"max_stream_s": 0.4, "stream_poll_max_s": 0.1}


class Sleeps(list[float]):
    async def __call__(self, seconds: float) -> None:
        self.append(seconds)
        await asyncio.sleep(min(seconds, 0.2))


def _client(live: LiveServer, sleeps: Sleeps | None = None) -> AsyncClient:
    return AsyncClient(live.url, KEY_A, retry=FAST, sleep=Sleeps() if sleeps is None else sleeps)


def _gets(live: LiveServer, part: str) -> list[dict[str, str]]:
    return [h for method, path, h in live.app.seen if part in path and method == "GET"]


def test_retry_after_and_a_post_without_a_key(live, scene_tar):
    job = finished_job(live, scene_tar, run_stages({"segment": {"run.json": b"{}"}}))
    live.app.plan.append(Fault(f"/v1/jobs/{job}", "status", 503, {"Retry-After": "2"}))
    live.app.plan.append(Fault("/v1/jobs", "status", 503, method="POST"))
    sleeps = Sleeps()

    async def scenario() -> tuple[dict[str, Any], int]:
        async with _client(live, sleeps) as client:
            status = await client.status(job)
            with pytest.raises(ApiError) as refused:
                await client.submit(status["upload_id"])
            return status, refused.value.status

    status, refused = asyncio.run(scenario())
    assert status["status"] == "succeeded" and refused == 503
    assert sleeps == [2.0]  # the GET waited Retry-After; the POST was not retried


def test_a_dropped_download_resumes(live, scene_tar, tmp_path):
    job = finished_job(live, scene_tar, run_stages({"segment": {"scene_labelled.ply": PAYLOAD}}))
    live.app.plan.append(Fault(NAME, "drop", after=700_000))

    async def scenario() -> list[Any]:
        async with _client(live) as client:
            return await client.download(job, tmp_path)

    [path] = asyncio.run(scenario())
    assert path.read_bytes() == PAYLOAD
    assert [h.get("range") for h in _gets(live, NAME)] == [None, "bytes=700000-"]


def test_follow_reconnects_after_a_dropped_stream(live, scene, tmp_path):
    job = queued_job(live, tar_bytes(scene))
    stages = [FakeStage(n, steps=3, on_step=lambda i: __import__("time").sleep(0.1)) for n in "ab"]
    thread = threading.Thread(target=execute, args=(live, job, stages))
    live.app.plan.append(Fault(f"/v1/jobs/{job}/events", "drop", after=300))
    seen: list[ServerEvent] = []

    async def scenario() -> dict[str, Any]:
        async with _client(live) as client:
            return await client.follow(job, on_event=seen.append, timeout=60)

    thread.start()
    try:
        assert asyncio.run(scenario())["status"] == "succeeded"
    finally:
        thread.join(30)
    ids = [e.id for e in seen]
    assert ids == list(range(1, len(ids) + 1)) and seen[-1].type == "completed"
    assert int(_gets(live, f"/v1/jobs/{job}/events")[1]["last-event-id"]) >= 1


def test_follow_a_failed_job(live, scene_tar):
    job = queued_job(live, scene_tar)
    assert execute(live, job, [FakeStage("a", steps=1, fail=RuntimeError("x"))]) == "failed"

    async def scenario() -> None:
        async with _client(live) as client:
            await client.follow(job)

    with pytest.raises(JobFailed, match=f"job {job} failed"):
        asyncio.run(scenario())
