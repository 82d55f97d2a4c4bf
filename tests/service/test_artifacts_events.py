"""Artifacts (listing, ETag, Range, traversal) and server-sent events (replay, end)."""

from __future__ import annotations

import hashlib

import pytest

from service.artifacts import parse_range
from service.problems import ApiProblem
from tests.service.conftest import AUTH_A, assert_problem, state_of
from tests.worker.fakes import FakeStage
from worker.execute import execute_job

BLOB = bytes(range(256)) * 40  # 10240 bytes


@pytest.fixture
def done_job(client, upload_id) -> str:
    state = state_of(client)
    job_id: str = client.post("/v1/jobs", json={"upload_id": upload_id}, headers=AUTH_A).json()[
        "id"
    ]
    stages = [FakeStage("one"), FakeStage("two", files={"scene.ply": BLOB, "deep/x.json": b"{}"})]
    assert execute_job(job_id, state.store, state.settings, stages=stages) == "succeeded"
    return job_id


def test_listing(client, done_job):
    listing = client.get(f"/v1/jobs/{done_job}/artifacts", headers=AUTH_A).json()["artifacts"]
    by_name = {a["name"]: a for a in listing}
    assert list(by_name) == ["one/out.txt", "two/deep/x.json", "two/scene.ply"]
    ply = by_name["two/scene.ply"]
    assert ply["size"] == len(BLOB) and ply["sha256"] == hashlib.sha256(BLOB).hexdigest()
    assert ply["url"] == f"/v1/jobs/{done_job}/artifacts/two/scene.ply"
    assert by_name["two/deep/x.json"]["media_type"] == "application/json"


def test_download_etag_and_ranges(client, done_job):
    url = f"/v1/jobs/{done_job}/artifacts/two/scene.ply"
    full = client.get(url, headers=AUTH_A)
    assert full.status_code == 200 and full.content == BLOB
    etag = full.headers["etag"]
    assert (
        etag == f'"{hashlib.sha256(BLOB).hexdigest()}"' and full.headers["accept-ranges"] == "bytes"
    )
    assert client.get(url, headers={**AUTH_A, "If-None-Match": etag}).status_code == 304
    part = client.get(url, headers={**AUTH_A, "Range": "bytes=100-199"})
    assert part.status_code == 206 and part.content == BLOB[100:200]
    assert part.headers["content-range"] == f"bytes 100-199/{len(BLOB)}"
    tail = client.get(url, headers={**AUTH_A, "Range": "bytes=-10"})
    assert tail.status_code == 206 and tail.content == BLOB[-10:]
    open_end = client.get(url, headers={**AUTH_A, "Range": "bytes=10000-"})
    assert open_end.content == BLOB[10000:]
    beyond = client.get(url, headers={**AUTH_A, "Range": f"bytes={len(BLOB)}-"})
    assert assert_problem(beyond, 416) and beyond.headers["content-range"] == f"bytes */{len(BLOB)}"
    stale = client.get(url, headers={**AUTH_A, "Range": "bytes=0-9", "If-Range": '"old"'})
    assert stale.status_code == 200 and stale.content == BLOB
    multi = client.get(url, headers={**AUTH_A, "Range": "bytes=0-1,5-6"})
    assert multi.status_code == 200 and multi.content == BLOB


@pytest.mark.parametrize(
    "name",
    [
        "../manifest.json",
        "manifest.json",
        "two/../../../../etc/passwd",
        "%2e%2e/%2e%2e/dcseg.db",
        "two",
        "nope.txt",
    ],
)
def test_only_listed_files_are_served(client, done_job, name):
    assert_problem(client.get(f"/v1/jobs/{done_job}/artifacts/{name}", headers=AUTH_A), 404)


def test_parse_range():
    assert parse_range(None, 10) is None
    assert parse_range("bytes=2-4", 10) == (2, 4)
    assert parse_range("bytes=2-400", 10) == (2, 9)
    assert parse_range("bytes=-3", 10) == (7, 9)
    assert parse_range("bytes=5-2", 10) is None
    assert parse_range("items=0-1", 10) is None
    with pytest.raises(ApiProblem):
        parse_range("bytes=10-", 10)
    with pytest.raises(ApiProblem):
        parse_range("bytes=-0", 10)


def _events(text: str) -> list[dict[str, str]]:
    out = []
    for block in text.strip().split("\n\n"):
        fields = dict(
            line.split(": ", 1)
            for line in block.splitlines()
            if not line.startswith((":", "retry"))
        )
        if fields:
            out.append(fields)
    return out


def test_events_replay_and_end(client, done_job):
    url = f"/v1/jobs/{done_job}/events"
    with client.stream("GET", url, headers=AUTH_A) as response:
        assert response.headers["content-type"].startswith("text/event-stream")
        events = _events(response.read().decode())
    ids = [int(e["id"]) for e in events]
    assert ids == list(range(1, len(ids) + 1))
    assert events[0]["event"] == "status" and events[-1]["event"] == "completed"
    assert {e["event"] for e in events} <= {"status", "progress", "log", "completed"}
    assert '"succeeded"' in events[-1]["data"]
    with client.stream("GET", url, headers={**AUTH_A, "Last-Event-ID": str(ids[-3])}) as response:
        replay = _events(response.read().decode())
    assert [int(e["id"]) for e in replay] == ids[-2:]
    assert_problem(client.get(url, headers={**AUTH_A, "Last-Event-ID": "x"}), 422)


def test_events_follow_a_running_job(client, upload_id):
    import threading

    state = state_of(client)
    job_id = client.post("/v1/jobs", json={"upload_id": upload_id}, headers=AUTH_A).json()["id"]
    runner = threading.Thread(
        target=execute_job,
        args=(job_id, state.store, state.settings),
        kwargs={
            "stages": [FakeStage("slow", steps=5, on_step=lambda i: __import__("time").sleep(0.1))]
        },
    )
    with client.stream("GET", f"/v1/jobs/{job_id}/events", headers=AUTH_A) as response:
        runner.start()
        events = _events(response.read().decode())
    runner.join()
    assert events[-1]["event"] == "completed"
    assert any(e["event"] == "progress" for e in events)
