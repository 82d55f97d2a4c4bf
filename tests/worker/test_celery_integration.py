"""A real Celery worker process (``dcseg worker --pool solo``) running a job from Redis.

Needs Redis on ``DCSEG_TEST_REDIS`` (default ``redis://127.0.0.1:6379/15``); skipped with the
reason when it is unreachable. Each run uses its own queue name, so runs never share jobs.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any
from urllib.parse import urlparse

import pytest
import redis

from jobstore.contract import TASK_RUN_JOB, JobPaths
from service.main import create_app
from service.queue import marker_key
from tests.service.conftest import (
    AUTH_A,
    TAR,
    TestClient,
    make_settings,
    reachable,
    state_of,
    tar_bytes,
    wait_for,
)
from tests.worker.conftest import worker_log, worker_processes

REDIS_URL = os.environ.get("DCSEG_TEST_REDIS", "redis://127.0.0.1:6379/15")

pytestmark = pytest.mark.integration


def _redis_reachable() -> bool:
    parsed = urlparse(REDIS_URL)
    return reachable(parsed.hostname or "127.0.0.1", parsed.port or 6379)


@pytest.fixture
def celery_env(tmp_path: Path) -> Iterator[dict[str, str]]:
    if not _redis_reachable():
        pytest.skip(f"Redis not reachable at {REDIS_URL}")
    env = {
        **os.environ,
        "DCSEG_BROKER_URL": REDIS_URL,
        "DCSEG_STORAGE_DIR": str(tmp_path / "data"),
        "DCSEG_DATABASE_URL": f"sqlite:///{tmp_path / 'data' / 'dcseg.db'}",
        "DCSEG_GPU_QUEUE": f"gpu-test-{uuid.uuid4().hex[:8]}",
        "DCSEG_DEVICE": "cpu",
        "DCSEG_HEARTBEAT_S": "1",
    }
    yield env
    _forget_queue(env["DCSEG_GPU_QUEUE"])


def _forget_queue(queue: str) -> None:
    """Drop this run's queue and its unacknowledged messages from the shared Redis."""
    broker = redis.Redis.from_url(REDIS_URL)
    try:
        broker.delete(
            queue,
            f"_kombu.binding.{queue}",
            f"_kombu.binding_permanent.{queue}",
            marker_key(queue),
        )
        for tag, raw in broker.hgetall("unacked").items():
            try:
                routing_key = json.loads(raw)[2]
            except (ValueError, IndexError, TypeError):
                continue
            if routing_key == queue:
                broker.hdel("unacked", tag)
                broker.zrem("unacked_index", tag)
    finally:
        broker.close()


@pytest.fixture
def start_worker(
    celery_env: dict[str, str], tmp_path: Path
) -> Iterator[Callable[[], subprocess.Popen[bytes]]]:
    """Starts ``dcseg worker --pool solo`` processes; stops them after the test."""
    (tmp_path / "data").mkdir(exist_ok=True)
    with worker_processes(celery_env, tmp_path) as start:
        yield start


def test_job_survives_a_lost_queue_and_runs_in_a_worker_process(
    celery_env, start_worker, scene, tmp_path
):
    """The API enqueues ``dcseg.run_job`` by name; when the broker loses the message (Redis
    restarted without persistence), the next API start re-sends the queued job, and a separate
    worker process runs it to the end."""
    settings = make_settings(
        tmp_path,
        broker_url=celery_env["DCSEG_BROKER_URL"],
        database_url=celery_env["DCSEG_DATABASE_URL"],
        gpu_queue=celery_env["DCSEG_GPU_QUEUE"],
    )
    queue = celery_env["DCSEG_GPU_QUEUE"]
    broker = redis.Redis.from_url(REDIS_URL)
    try:
        with TestClient(create_app(settings)) as client:
            ready = client.get("/readyz")
            assert ready.status_code == 200 and ready.json()["checks"]["broker"] == "ok"
            upload = client.post("/v1/uploads", content=tar_bytes(scene), headers={**AUTH_A, **TAR})
            body = {
                "upload_id": upload.json()["id"],
                "options": {
                    "reconstruct": {"iterations": 2, "holdout": 0},
                    "affinity": {"iterations": 5, "rays": 64},
                },
            }
            job_id = client.post("/v1/jobs", json=body, headers=AUTH_A).json()["id"]
        messages = [json.loads(m) for m in broker.lrange(queue, 0, -1)]
        assert [m["headers"]["task"] for m in messages] == [TASK_RUN_JOB]
        assert job_id in messages[0]["headers"]["argsrepr"]
        broker.delete(queue)  # the broker forgets the job
        worker = start_worker()
        with TestClient(create_app(settings)) as client:

            def finished() -> Any:
                assert worker.poll() is None, worker_log(tmp_path, 3000)
                job = client.get(f"/v1/jobs/{job_id}", headers=AUTH_A).json()
                return job if job["status"] in ("succeeded", "failed", "canceled") else None

            job = wait_for(finished, timeout=120, every=0.25)
            assert job["status"] == "succeeded", (job, worker_log(tmp_path, 3000))
            listing = client.get(f"/v1/jobs/{job_id}/artifacts", headers=AUTH_A).json()
            assert "reconstruct/scene.ply" in [a["name"] for a in listing["artifacts"]]
    finally:
        broker.delete(queue)
        broker.close()


def test_killed_worker_job_resumes_after_last_finished_stage(
    celery_env, start_worker, scene, tmp_path
):
    """SIGKILL a worker mid-reconstruction: the API notices the stale lease, requeues the job,
    and a second worker resumes it after ``validate`` without duplicate or partial artifacts."""
    celery_env["DCSEG_HEARTBEAT_S"] = "1.0"
    settings = make_settings(
        tmp_path,
        broker_url=celery_env["DCSEG_BROKER_URL"],
        database_url=celery_env["DCSEG_DATABASE_URL"],
        gpu_queue=celery_env["DCSEG_GPU_QUEUE"],
        heartbeat_s=1.0,
        sweep_interval_s=0.3,
    )
    first = start_worker()
    with TestClient(create_app(settings)) as client:
        upload = client.post("/v1/uploads", content=tar_bytes(scene), headers={**AUTH_A, **TAR})
        body = {
            "upload_id": upload.json()["id"],
            "options": {
                "reconstruct": {"iterations": 40, "holdout": 0},
                "affinity": {"iterations": 5, "rays": 64},
            },
        }
        job_id = client.post("/v1/jobs", json=body, headers=AUTH_A).json()["id"]

        def training() -> bool:
            job = client.get(f"/v1/jobs/{job_id}", headers=AUTH_A).json()
            return "step" in (job["progress"]["message"] or "")

        wait_for(training, timeout=60, every=0.2)
        first.kill()
        first.wait(10)
        start_worker()

        def finished() -> Any:
            job = client.get(f"/v1/jobs/{job_id}", headers=AUTH_A).json()
            return job if job["status"] in ("succeeded", "failed", "canceled") else None

        job = wait_for(finished, timeout=120, every=0.2)
        assert job["status"] == "succeeded", (job, worker_log(tmp_path, 3000))
        state = state_of(client)
        record = state.store.get_job(job_id)
        assert record is not None and record.attempts == 2
        messages = [e.data.get("message") for e in state.store.events_after(job_id, 0)]
        assert "validate: already finished" in messages
        assert "worker lost; requeued" in messages
        listing = client.get(f"/v1/jobs/{job_id}/artifacts", headers=AUTH_A).json()
        names = [a["name"] for a in listing["artifacts"]]
        assert sorted(names) == sorted(set(names))
        for item in listing["artifacts"]:
            data = client.get(item["url"], headers=AUTH_A).content
            assert hashlib.sha256(data).hexdigest() == item["sha256"]
        assert not list(JobPaths(settings.storage_dir, job_id).output.glob(".tmp-*"))
