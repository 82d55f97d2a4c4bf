"""``dcseg wait`` and ``Client.follow`` against a real server: the event stream with a
progress bar, reconnection with ``Last-Event-ID`` after a dropped stream or the stream's
lifetime, polling when the stream is refused, and the exit codes of each ending."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from typing import Any

import httpx
import pytest

from dcseg.cli import main
from dcseg.client import Client, JobFailed, RetryPolicy, ServerEvent
from tests.service.conftest import AUTH_A, KEY_A
from tests.service.live import Fault, LiveServer, execute, live, queued_job
from tests.worker.fakes import FakeStage

__all__ = ["live"]


@pytest.fixture
def live_overrides() -> dict[str, Any]:
    """Streams end after 0.4 s: every wait below reconnects with Last-Event-ID."""
    return {"max_stream_s": 0.4, "stream_poll_max_s": 0.1}


def _stages(fail: Exception | None = None) -> list[FakeStage]:
    import time

    def slow(i: int) -> None:
        time.sleep(0.1)

    return [
        FakeStage("validate", steps=3, on_step=slow),
        FakeStage("reconstruct", steps=3, on_step=slow),
        FakeStage("segment", steps=3, on_step=slow, fail=fail),
    ]


@pytest.fixture
def running(live: LiveServer, scene_tar: bytes) -> Iterator[tuple[str, list[str]]]:
    """A job whose stages run in a thread (about 1 s); yields its id and (later) its end."""
    job = queued_job(live, scene_tar)
    ended: list[str] = []
    thread = threading.Thread(target=lambda: ended.append(execute(live, job, _stages())))
    thread.start()
    yield job, ended
    thread.join(30)


def _wait(live: LiveServer, job: str, *extra: str) -> int:
    return main(["wait", job, "--url", live.url, "--api-key", KEY_A, *extra])


def _requests(live: LiveServer, path: str) -> list[dict[str, str]]:
    return [h for method, p, h in live.app.seen if p == path and method == "GET"]


def test_wait_follows_the_stream_with_a_progress_bar(live, running, capsys):
    job, _ = running
    assert _wait(live, job) == 0
    printed = capsys.readouterr()
    assert printed.out == f"{job} succeeded\n"
    assert "segment" in printed.err and "segment: step 3/3" in printed.err
    assert "succeeded" in printed.err.splitlines()[-1]
    assert len(_requests(live, f"/v1/jobs/{job}/events")) >= 2  # lifetime 0.4 s: reconnected
    assert len(_requests(live, f"/v1/jobs/{job}")) == 1  # the final read; no polling


def test_a_dropped_stream_resumes_after_the_last_event(live, running):
    job, _ = running
    live.app.plan.append(Fault(f"/v1/jobs/{job}/events", "drop", after=400))
    seen: list[ServerEvent] = []
    fast = RetryPolicy(backoff_s=0.05, max_backoff_s=0.1)
    with Client(live.url, KEY_A, retry=fast) as client:
        assert client.follow(job, on_event=seen.append, timeout=60)["status"] == "succeeded"
    ids = [e.id for e in seen]
    assert ids == list(range(1, len(ids) + 1))  # nothing missed, nothing twice
    assert seen[-1].type == "completed" and len(ids) >= 10
    streams = _requests(live, f"/v1/jobs/{job}/events")
    resumed = int(streams[1]["last-event-id"])
    assert 1 <= resumed < len(ids)  # the second connection began after the dropped one's last


def test_without_a_stream_it_polls(live, running, capsys):
    job, _ = running
    live.app.plan.append(Fault(f"/v1/jobs/{job}/events", "status", 429, times=100))
    assert _wait(live, job, "--quiet") == 0
    assert capsys.readouterr().out == f"{job} succeeded\n"
    assert len(_requests(live, f"/v1/jobs/{job}")) >= 2


def test_a_failed_job_exits_1_with_its_reason(live, scene_tar, capsys):
    job = queued_job(live, scene_tar)
    thread = threading.Thread(target=execute, args=(live, job, _stages(RuntimeError("x"))))
    thread.start()
    try:
        assert _wait(live, job) == 1
    finally:
        thread.join(30)
    err = capsys.readouterr().err.splitlines()
    assert err[-1].startswith(f"dcseg wait: job {job} failed: ")
    with Client(live.url, KEY_A) as client, pytest.raises(JobFailed) as failed:
        client.follow(job)
    assert failed.value.job["status"] == "failed"


def test_timeouts_and_unknown_jobs(live, scene_tar, capsys):
    job = queued_job(live, scene_tar)  # never run
    assert _wait(live, job, "--timeout", "0.5", "--quiet") == 5
    assert capsys.readouterr().err == f"dcseg wait: job {job} still running after 0.5 s\n"
    assert _wait(live, "no-such-job", "--quiet") == 4
    assert capsys.readouterr().err.startswith("dcseg wait: HTTP 404 ")


def test_a_canceled_job_exits_1_naming_the_stage(live, scene_tar, capsys):
    job = queued_job(live, scene_tar)
    cancel = httpx.post(f"{live.url}/v1/jobs/{job}:cancel", headers=AUTH_A)
    assert cancel.status_code < 300, cancel.text
    assert _wait(live, job, "--quiet") == 1
    assert capsys.readouterr().err == f"dcseg wait: job {job} canceled: canceled on request\n"


def test_reasons_are_one_line():
    from dcseg.client.errors import reason

    error = {"type": "invalid-input", "detail": "frames/0.png:\n unreadable"}
    assert reason({"status": "failed", "error": error}) == "invalid-input: frames/0.png: unreadable"
    canceled = {"status": "canceled", "error": None, "progress": {"stage": "segment"}}
    assert reason(canceled) == "canceled on request during segment"
    assert reason({"status": "failed", "error": None}) == "no reason given"


def test_poll_shows_progress_without_the_stream(live, running, capsys):
    job, _ = running
    assert _wait(live, job, "--poll") == 0
    printed = capsys.readouterr()
    assert printed.out == f"{job} succeeded\n" and "%|" in printed.err  # the bar was drawn
    assert _requests(live, f"/v1/jobs/{job}/events") == []
