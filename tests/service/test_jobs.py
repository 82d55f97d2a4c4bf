"""``/v1/jobs``: create, read, list, cancel, delete, idempotency, limits and tenant isolation."""

from __future__ import annotations

import threading
from typing import Any

import pytest

from jobstore.contract import TASK_RUN_JOB, JobPaths
from service.deps import RateLimiter
from service.queue import CeleryQueue
from tests.service.conftest import AUTH_A, AUTH_B, assert_problem, make_settings, state_of
from tests.worker.fakes import FakeStage, RecordingQueue
from worker.execute import execute_job


@pytest.fixture
def queue(client) -> RecordingQueue:
    recording = RecordingQueue()
    state_of(client).queue = recording
    return recording


def submit(client: Any, upload_id: str, headers: dict[str, str] = AUTH_A, **extra: Any) -> Any:
    return client.post("/v1/jobs", json={"upload_id": upload_id, **extra}, headers=headers)


def run_fake(client, job_id, stages=None) -> str:
    state = state_of(client)
    stages = stages or [
        FakeStage("one"),
        FakeStage("two", files={"sub/b.bin": bytes(range(256)) * 4}),
    ]
    return execute_job(job_id, state.store, state.settings, stages=stages)


def test_create_answers_202_and_enqueues(client, upload_id, queue):
    response = submit(client, upload_id, options={"reconstruct": {"iterations": 5}})
    assert response.status_code == 202, response.text
    job = response.json()
    assert response.headers["location"] == f"/v1/jobs/{job['id']}"
    assert response.headers["operation-location"] == response.headers["location"]
    assert int(response.headers["retry-after"]) > 0
    assert job["status"] == "queued" and job["upload_id"] == upload_id
    assert job["config"]["options"]["reconstruct"] == {"iterations": 5}
    assert set(job["links"]) == {"self", "cancel", "events", "artifacts"}
    assert queue.job_ids == [job["id"]]


def test_celery_queue_sends_by_task_name(settings):
    sent = []
    celery_queue = CeleryQueue(settings.model_copy(update={"broker_url": "redis://127.0.0.1:1/0"}))
    celery_queue.app.send_task = lambda name, args, queue: sent.append((name, args, queue))
    celery_queue.enqueue("job-1")
    assert sent == [(TASK_RUN_JOB, ["job-1"], "gpu")]


def test_get_has_etag_and_retry_after(client, upload_id, queue):
    job_id = submit(client, upload_id).json()["id"]
    first = client.get(f"/v1/jobs/{job_id}", headers=AUTH_A)
    assert first.status_code == 200 and first.headers["retry-after"]
    etag = first.headers["etag"]
    same = client.get(f"/v1/jobs/{job_id}", headers={**AUTH_A, "If-None-Match": etag})
    assert same.status_code == 304
    assert run_fake(client, job_id) == "succeeded"
    done = client.get(f"/v1/jobs/{job_id}", headers={**AUTH_A, "If-None-Match": etag})
    assert done.status_code == 200 and done.headers["etag"] != etag
    assert "retry-after" not in done.headers
    body = done.json()
    assert body["status"] == "succeeded" and body["progress"]["fraction"] == 1.0
    assert body["started_at"] and body["completed_at"]


def test_unknown_job_and_other_tenant(client, upload_id, queue):
    job_id = submit(client, upload_id).json()["id"]
    assert_problem(client.get("/v1/jobs/nope", headers=AUTH_A), 404)
    for method, path in [
        ("GET", f"/v1/jobs/{job_id}"),
        ("POST", f"/v1/jobs/{job_id}:cancel"),
        ("DELETE", f"/v1/jobs/{job_id}"),
        ("GET", f"/v1/jobs/{job_id}/events"),
        ("GET", f"/v1/jobs/{job_id}/artifacts"),
    ]:
        assert_problem(client.request(method, path, headers=AUTH_B), 404)
    assert client.get("/v1/jobs", headers=AUTH_B).json()["jobs"] == []
    assert_problem(submit(client, upload_id, headers=AUTH_B), 404)  # upload of tenant a


def test_bad_bodies(client, upload_id, queue):
    raw = client.post(
        "/v1/jobs",
        content=b'{"upload_id": ',
        headers={**AUTH_A, "Content-Type": "application/json"},
    )
    assert assert_problem(raw, 400)["type"].endswith("malformed-json")
    invalid = submit(client, upload_id, preset="No Such!", options={"capture": {"stride": 0}})
    paths = {e["path"] for e in assert_problem(invalid, 422)["errors"]}
    assert {"body.preset", "body.options.capture"} <= {p.rsplit(".stride", 1)[0] for p in paths}
    assert_problem(client.post("/v1/jobs", json={}, headers=AUTH_A), 422)
    assert_problem(
        client.post("/v1/jobs", json={"upload_id": "x", "bogus": 1}, headers=AUTH_A), 422
    )
    assert_problem(submit(client, "no-such-upload"), 404)
    assert queue.job_ids == []


def test_idempotency(client, upload_id, queue):
    headers = {**AUTH_A, "Idempotency-Key": "k1"}
    first = client.post("/v1/jobs", json={"upload_id": upload_id}, headers=headers)
    again = client.post("/v1/jobs", json={"upload_id": upload_id}, headers=headers)
    assert first.status_code == again.status_code == 202
    assert again.json() == first.json() and again.headers["location"] == first.headers["location"]
    assert again.headers["idempotent-replayed"] == "true"
    assert len(queue.job_ids) == 1
    other = client.post(
        "/v1/jobs", json={"upload_id": upload_id, "preset": "paper"}, headers=headers
    )
    assert assert_problem(other, 422)["type"].endswith("idempotency-mismatch")
    # the key is per tenant
    assert (
        client.post(
            "/v1/jobs", json={"upload_id": upload_id}, headers={**AUTH_B, "Idempotency-Key": "k1"}
        ).status_code
        == 404
    )


def test_idempotency_in_flight(client, upload_id, queue, monkeypatch):
    state = state_of(client)
    started, release = threading.Event(), threading.Event()
    original = state.queue.enqueue

    def slow_enqueue(job_id):
        started.set()
        release.wait(10)
        original(job_id)

    monkeypatch.setattr(state.queue, "enqueue", slow_enqueue)
    headers = {**AUTH_A, "Idempotency-Key": "slow"}
    results: dict[str, Any] = {}
    thread = threading.Thread(
        target=lambda: results.setdefault(
            "first", client.post("/v1/jobs", json={"upload_id": upload_id}, headers=headers)
        )
    )
    thread.start()
    assert started.wait(10)
    second = client.post("/v1/jobs", json={"upload_id": upload_id}, headers=headers)
    release.set()
    thread.join(10)
    assert assert_problem(second, 409)["type"].endswith("idempotency-in-flight")
    assert results["first"].status_code == 202


def test_failed_request_releases_the_key(client, upload_id, queue):
    headers = {**AUTH_A, "Idempotency-Key": "retry-me"}
    assert_problem(client.post("/v1/jobs", json={"upload_id": "missing"}, headers=headers), 404)
    assert (
        client.post("/v1/jobs", json={"upload_id": "missing"}, headers=headers).status_code == 404
    )


def test_list_pages_and_filters(client, upload_id, queue, settings):
    state_of(client).settings = settings.model_copy(update={"max_running_jobs_per_tenant": 50})
    ids = [submit(client, upload_id).json()["id"] for _ in range(5)]
    run_fake(client, ids[0])
    seen, token, pages = [], None, 0
    while True:
        params = {"page_size": 2} | ({"page_token": token} if token else {})
        page = client.get("/v1/jobs", params=params, headers=AUTH_A).json()
        seen += [j["id"] for j in page["jobs"]]
        pages += 1
        token = page.get("next_page_token")
        if not token:
            break
    assert seen == ids[::-1] and pages == 3
    succeeded = client.get("/v1/jobs", params={"status": "succeeded"}, headers=AUTH_A).json()
    assert [j["id"] for j in succeeded["jobs"]] == [ids[0]] and succeeded["next_page_token"] is None
    assert_problem(client.get("/v1/jobs", params={"page_token": "garbage!"}, headers=AUTH_A), 400)
    first = client.get("/v1/jobs", params={"page_size": 2}, headers=AUTH_A).json()
    mixed = {"page_token": first["next_page_token"], "status": "queued"}
    assert_problem(client.get("/v1/jobs", params=mixed, headers=AUTH_A), 400)
    assert_problem(client.get("/v1/jobs", params={"status": "weird"}, headers=AUTH_A), 422)
    assert_problem(client.get("/v1/jobs", params={"page_size": 0}, headers=AUTH_A), 422)


def test_cancel_queued_then_terminal(client, upload_id, queue):
    job_id = submit(client, upload_id).json()["id"]
    response = client.post(f"/v1/jobs/{job_id}:cancel", headers=AUTH_A)
    assert response.status_code == 200 and response.json()["status"] == "canceled"
    assert_problem(client.post(f"/v1/jobs/{job_id}:cancel", headers=AUTH_A), 409)
    assert run_fake(client, job_id) == "skipped"  # a late delivery does nothing


def test_cancel_running_stops_between_iterations(client, upload_id, queue):
    job_id = submit(client, upload_id).json()["id"]
    calls = []

    def cancel_at_step(i):
        if i == 1:
            calls.append(client.post(f"/v1/jobs/{job_id}/cancel", headers=AUTH_A))

    status = run_fake(
        client, job_id, [FakeStage("one", steps=4, on_step=cancel_at_step), FakeStage("two")]
    )
    assert calls[0].json()["status"] == "canceling"
    assert status == "canceled"
    assert client.get(f"/v1/jobs/{job_id}", headers=AUTH_A).json()["status"] == "canceled"


def test_delete(client, upload_id, queue):
    job_id = submit(client, upload_id).json()["id"]
    assert_problem(client.delete(f"/v1/jobs/{job_id}", headers=AUTH_A), 409)
    run_fake(client, job_id)
    folder = JobPaths(state_of(client).settings.storage_dir, job_id).folder
    assert folder.exists()
    assert client.delete(f"/v1/jobs/{job_id}", headers=AUTH_A).status_code == 204
    assert not folder.exists()
    assert_problem(client.get(f"/v1/jobs/{job_id}", headers=AUTH_A), 404)
    assert_problem(client.delete(f"/v1/jobs/{job_id}", headers=AUTH_A), 404)


def test_running_job_cap(client, upload_id, queue, settings):
    state_of(client).settings = settings.model_copy(update={"max_running_jobs_per_tenant": 2})
    assert submit(client, upload_id).status_code == 202
    assert submit(client, upload_id).status_code == 202
    third = submit(client, upload_id)
    assert_problem(third, 429)
    assert int(third.headers["retry-after"]) > 0


def test_rate_limit(client):
    state_of(client).limiter = RateLimiter(3)
    for _ in range(3):
        assert client.get("/v1/jobs", headers=AUTH_A).status_code == 200
    limited = client.get("/v1/jobs", headers=AUTH_A)
    assert_problem(limited, 429)
    assert 1 <= int(limited.headers["retry-after"]) <= 60
    assert client.get("/v1/jobs", headers=AUTH_B).status_code == 200  # per tenant


def test_rate_limiter_windows():
    limiter = RateLimiter(1)
    assert limiter.hit("t", now=120.0) is None
    assert limiter.hit("t", now=150.0) == 30
    assert limiter.hit("t", now=180.0) is None


def test_derived_job_reuses_parent_stages(client, upload_id, queue):
    parent_id = submit(client, upload_id).json()["id"]
    one, two = FakeStage("one"), FakeStage("two")
    run_fake(client, parent_id, [one, two])
    child = client.post("/v1/jobs", json={"parent_job_id": parent_id}, headers=AUTH_A)
    assert child.status_code == 202 and child.json()["upload_id"] == upload_id
    assert run_fake(client, child.json()["id"], [one, two]) == "succeeded"
    assert one.runs == two.runs == 1  # both reused, not recomputed
    listing = client.get(f"/v1/jobs/{child.json()['id']}/artifacts", headers=AUTH_A).json()
    assert [a["name"] for a in listing["artifacts"]] == ["one/out.txt", "two/out.txt"]
    changed = {"parent_job_id": parent_id, "options": {"reconstruct": {"iterations": 7}}}
    other = client.post("/v1/jobs", json=changed, headers=AUTH_A).json()["id"]
    assert run_fake(client, other, [one, two]) == "succeeded"
    assert one.runs == two.runs == 2  # parameters changed: recomputed


def test_derived_job_needs_finished_parent(client, upload_id, queue):
    parent_id = submit(client, upload_id).json()["id"]
    assert_problem(client.post("/v1/jobs", json={"parent_job_id": parent_id}, headers=AUTH_A), 409)
    assert_problem(client.post("/v1/jobs", json={"parent_job_id": "nope"}, headers=AUTH_A), 404)


def test_queue_down_answers_503(client, upload_id, queue, monkeypatch):
    def broken(job_id):
        raise ConnectionError("broker down")

    monkeypatch.setattr(state_of(client).queue, "enqueue", broken)
    assert_problem(submit(client, upload_id), 503)
    jobs = client.get("/v1/jobs", headers=AUTH_A).json()["jobs"]
    assert [j["status"] for j in jobs] == ["failed"]


def test_queue_failure_error_carries_no_broker_text(client, upload_id, queue, monkeypatch):
    """Job errors carry raw exception text (storage paths, broker URLs): the enqueue failure
    too. The failed job's error has a type and an error id, not the exception's text."""

    def broken(job_id: str) -> None:
        raise ConnectionError("Error 111 connecting to redis://:s3cret@10.0.0.7:6379/0")

    monkeypatch.setattr(state_of(client).queue, "enqueue", broken)
    assert_problem(submit(client, upload_id, options={}), 503)
    job = client.get("/v1/jobs", headers=AUTH_A).json()["jobs"][0]
    assert job["status"] == "failed" and job["error"]["type"] == "queue-unavailable"
    assert job["error"]["error_id"] in job["error"]["detail"]
    assert "redis" not in str(job["error"]) and "s3cret" not in str(job["error"])


def test_no_keys_means_local_tenant(tmp_path):
    from service.main import create_app
    from tests.service.conftest import TestClient

    app = create_app(make_settings(tmp_path, api_keys=""))
    with TestClient(app, base_url="http://127.0.0.1", client=("127.0.0.1", 1)) as local:
        assert local.get("/v1/jobs").status_code == 200
