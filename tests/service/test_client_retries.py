"""``dcseg.client.Client`` against a real server with injected faults: 503/429 with
``Retry-After``, connections dropped mid-body, a server ignoring ``Range``, a restart during a
download, an unreachable server; and which requests are never sent twice."""

from __future__ import annotations

import os
from datetime import UTC, datetime, timedelta
from email.utils import format_datetime

import pytest

from dcseg.client import ApiError, Client, NetworkError, RetryPolicy, retry_after
from tests.service.conftest import KEY_A, free_port
from tests.service.live import Fault, LiveServer, finished_job, live, live_overrides, run_stages

__all__ = ["live", "live_overrides"]

PAYLOAD = os.urandom(3 << 20)
FAST = RetryPolicy(attempts=6, total_s=30, backoff_s=0.05, max_backoff_s=0.2)
NAME = "segment/scene_labelled.ply"


class Sleeps(list[float]):
    """Records the client's waits (and waits them, shortened)."""

    def __call__(self, seconds: float) -> None:
        import time

        self.append(seconds)
        time.sleep(min(seconds, 0.2))


@pytest.fixture
def sleeps() -> Sleeps:
    return Sleeps()


@pytest.fixture
def api(live: LiveServer, sleeps: Sleeps):
    with Client(live.url, KEY_A, retry=FAST, sleep=sleeps) as client:
        yield client


@pytest.fixture
def job(live: LiveServer, scene_tar: bytes) -> str:
    files = {"scene_labelled.ply": PAYLOAD, "instances.json": b"{}"}
    return finished_job(live, scene_tar, run_stages({"segment": files}))


def _gets(live: LiveServer, part: str) -> list[dict[str, str]]:
    return [headers for method, path, headers in live.app.seen if part in path and method == "GET"]


def test_503_with_retry_after_is_waited_for(live, api, job, sleeps):
    live.app.plan.append(Fault(f"/v1/jobs/{job}", "status", 503, {"Retry-After": "3"}))
    assert api.status(job)["status"] == "succeeded"
    assert sleeps == [3.0]  # the server's delay, not a computed backoff
    assert len(_gets(live, f"/v1/jobs/{job}")) == 2


def test_429_with_an_http_date_and_then_plain_backoff(live, api, job, sleeps):
    later = format_datetime(datetime.now(UTC) + timedelta(seconds=5), usegmt=True)
    live.app.plan.append(Fault("/artifacts", "status", 429, {"Retry-After": later}))
    live.app.plan.append(Fault("/artifacts", "status", 502))
    assert [a["name"] for a in api.artifacts(job)] == ["segment/instances.json", NAME]
    assert 3.0 < sleeps[0] <= 5.0 and 0 <= sleeps[1] <= FAST.backoff_s * 2


def test_retries_are_bounded(live, job, sleeps):
    live.app.plan.append(Fault(f"/v1/jobs/{job}", "status", 503, times=10))
    policy = RetryPolicy(attempts=3, total_s=30, backoff_s=0.01)
    with Client(live.url, KEY_A, retry=policy, sleep=sleeps) as client:
        with pytest.raises(ApiError) as failed:
            client.status(job)
    assert failed.value.status == 503 and str(failed.value).startswith("HTTP 503 injected")
    assert len(sleeps) == 2 and len(_gets(live, f"/v1/jobs/{job}")) == 3


def test_a_post_is_retried_only_with_an_idempotency_key(live, api, job, sleeps):
    upload = api.status(job)["upload_id"]
    live.app.plan.append(Fault("/v1/jobs", "status", 503, method="POST"))
    with pytest.raises(ApiError) as refused:
        api.submit(upload)
    assert refused.value.status == 503 and sleeps == []
    live.app.plan.append(Fault("/v1/jobs", "status", 503, {"Retry-After": "1"}, method="POST"))
    first = api.submit(upload, idempotency_key="k-1")
    assert sleeps == [1.0]
    assert api.submit(upload, idempotency_key="k-1")["id"] == first["id"]


def test_a_download_dropped_mid_body_resumes_with_range(live, api, job, tmp_path):
    live.app.plan.append(Fault(NAME, "drop", after=1 << 20))
    [path] = api.download(job, tmp_path, only=[NAME])
    assert path.read_bytes() == PAYLOAD
    first, second = _gets(live, NAME)
    assert "range" not in first
    assert second["range"] == f"bytes={1 << 20}-"
    assert second["if-range"].strip('"') == api.artifacts(job)[1]["sha256"]
    assert not list(tmp_path.rglob("*.part"))


def test_a_server_ignoring_range_restarts_the_file(live, api, job, tmp_path):
    live.app.plan.append(Fault(NAME, "drop", after=500_000))
    live.app.plan.append(Fault(NAME, "ignore-range"))
    [path] = api.download(job, tmp_path, only=[NAME])
    assert path.read_bytes() == PAYLOAD  # not the first 500 kB twice
    assert len(_gets(live, NAME)) == 2


def test_a_restart_during_a_download(live, job, tmp_path, sleeps):
    restart = lambda: live.restart(down_s=1.0)  # noqa: E731
    drop = Fault(NAME, "drop", after=2 << 20, then=restart, pause_s=0.5)
    live.app.plan.append(drop)
    patient = RetryPolicy(attempts=40, total_s=30, backoff_s=0.1, max_backoff_s=0.3)
    with Client(live.url, KEY_A, retry=patient, sleep=sleeps) as client:
        [path] = client.download(job, tmp_path, only=[NAME])
    assert path.read_bytes() == PAYLOAD
    assert live.restarts == 1 and len(sleeps) >= 2  # it waited for the server to return
    assert _gets(live, NAME)[-1]["range"] == f"bytes={2 << 20}-"


def test_a_stale_part_file_of_another_file_is_replaced(live, api, job, tmp_path):
    part = tmp_path / "segment" / "scene_labelled.ply.part"
    part.parent.mkdir(parents=True)
    part.write_bytes(b"x" * 1000)  # left by an earlier run against another job
    [path] = api.download(job, tmp_path, only=[NAME])
    assert path.read_bytes() == PAYLOAD
    ranges = [h.get("range") for h in _gets(live, NAME)]
    assert ranges == ["bytes=1000-", None]


def test_an_unreachable_service_is_a_network_error(sleeps):
    url = f"http://127.0.0.1:{free_port()}"
    policy = RetryPolicy(attempts=3, total_s=5, backoff_s=0.01)
    with Client(url, KEY_A, retry=policy, sleep=sleeps) as client:
        with pytest.raises(NetworkError) as failed:
            client.status("j")
    message = str(failed.value)
    assert message.startswith(f"GET {url}/v1/jobs/j failed") and "after 3 tries" in message
    assert len(sleeps) == 2 and "\n" not in message


def test_retry_after_forms():
    now = datetime(2026, 1, 1, tzinfo=UTC)
    assert retry_after("7") == 7.0
    assert retry_after(format_datetime(now + timedelta(seconds=30), usegmt=True), now) == 30.0
    assert retry_after(format_datetime(now - timedelta(seconds=30), usegmt=True), now) == 0.0
    assert retry_after(None) is None and retry_after("soon") is None and retry_after(" ") is None


def test_the_policy_backs_off_with_jitter_within_its_bounds():
    policy = RetryPolicy(attempts=5, total_s=10, backoff_s=1, max_backoff_s=3)
    for attempt, bound in ((1, 1), (2, 2), (3, 3), (4, 3)):
        waits = [policy.delay(attempt, 0) for _ in range(200)]
        assert all(w is not None and 0 <= w <= bound for w in waits)
        assert max(w for w in waits if w is not None) > bound / 2  # jittered, not fixed
    assert policy.delay(5, 0) is None  # attempts used up
    assert policy.delay(1, 9.5, server_delay=1) is None  # past total_s
    assert policy.delay(1, 0, server_delay=4) == 4  # Retry-After beyond max_backoff_s
    with pytest.raises(ValueError, match="attempts"):
        RetryPolicy(attempts=0)


def test_the_part_file_is_resumed_across_runs(live, api, job, tmp_path):
    """An interrupted earlier run left the first half: only the rest is fetched."""
    part = tmp_path / "segment" / "scene_labelled.ply.part"
    part.parent.mkdir(parents=True)
    part.write_bytes(PAYLOAD[: len(PAYLOAD) // 2])
    [path] = api.download(job, tmp_path, only=[NAME])
    assert path.read_bytes() == PAYLOAD
    assert [h.get("range") for h in _gets(live, NAME)] == [f"bytes={len(PAYLOAD) // 2}-"]


def test_cli_exit_codes_and_one_line_errors(live, job, monkeypatch, capsys):
    from dcseg.cli import main

    monkeypatch.setattr("dcseg.client.sync.RetryPolicy", lambda: FAST)
    down = f"http://127.0.0.1:{free_port()}"
    cases = [
        (down, job, 3, f"dcseg status: GET {down}/v1/jobs/{job} failed"),
        (live.url, "no-such-job", 4, "dcseg status: HTTP 404 "),
    ]
    live.app.plan.append(Fault(f"/v1/jobs/{job}", "status", 503, times=10))
    cases.append((live.url, job, 3, "dcseg status: HTTP 503 injected"))
    for url, job_id, code, start in cases:
        assert main(["status", job_id, "--url", url, "--api-key", KEY_A]) == code
        err = capsys.readouterr().err
        assert err.startswith(start) and err.count("\n") == 1, err
