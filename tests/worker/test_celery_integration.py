"""A real Celery worker process (``dcseg worker --pool solo``) running a job from Redis, and
stopping: SIGTERM interrupts its job for the next worker, a stuck stage's pool child is killed.

Needs Redis on ``DCSEG_TEST_REDIS`` (default ``redis://127.0.0.1:6379/15``); skipped with the
reason when it is unreachable. Each run uses its own queue name, so runs never share jobs.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import signal
import subprocess
import sys
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any
from urllib.parse import urlparse

import pytest
import redis

from jobstore.contract import TASK_RUN_JOB, JobPaths
from jobstore.models import Job, Upload
from jobstore.settings import Settings
from jobstore.store import Store
from service.main import create_app
from service.queue import CeleryQueue, marker_key
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
from tests.worker.conftest import REPO, add_job, worker_log, worker_processes
from tests.worker.test_time_limits import _timeout_detail
from worker.execute import read_manifest

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

        # generous: under a full test run the worker's start-up (imports, kernel cache) can
        # take most of a minute; the condition is polled, so a quick start is not slowed
        wait_for(training, timeout=180, every=0.2)
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


@pytest.fixture
def celery_job(tmp_path: Path) -> Iterator[tuple[dict[str, str], Store, str]]:
    """The environment of a Celery worker on a private queue, its store, and a queued job that
    was sent to the broker. Skipped without Redis."""
    if not _redis_reachable():
        pytest.skip(f"Redis not reachable at {REDIS_URL}")
    data = tmp_path / "data"
    env = {
        **os.environ,
        "DCSEG_BROKER_URL": REDIS_URL,
        "DCSEG_STORAGE_DIR": str(data),
        "DCSEG_DATABASE_URL": f"sqlite:///{data / 'dcseg.db'}",
        "DCSEG_GPU_QUEUE": f"gpu-test-{uuid.uuid4().hex[:8]}",
        "DCSEG_HEARTBEAT_S": "0.5",
    }
    settings = Settings(
        storage_dir=data,
        database_url=env["DCSEG_DATABASE_URL"],
        broker_url=REDIS_URL,
        gpu_queue=env["DCSEG_GPU_QUEUE"],
        heartbeat_s=0.5,
    )
    data.mkdir()
    store = Store(settings.db_url)
    store.init_schema()
    store.ensure_tenant("t")
    upload = Upload(id="u1", tenant_id="t", sha256="0" * 64, size=1, content_type="x", summary={})
    store.add_upload(upload)
    (data / "uploads" / "u1" / "data").mkdir(parents=True)
    job_id = add_job(store)
    CeleryQueue(settings).enqueue(job_id)
    try:
        yield env, store, job_id
    finally:
        store.close()
        _forget_queue(env["DCSEG_GPU_QUEUE"])


@contextlib.contextmanager
def _celery_worker(
    env: dict[str, str], log: Path, pool: str, **extra: str
) -> Iterator[subprocess.Popen[bytes]]:
    """``celery -A tests.worker.celery_test_app worker`` on the job's queue; killed on exit."""
    command = [sys.executable, "-m", "celery", "-A", "tests.worker.celery_test_app", "worker"]
    command += ["--pool", pool, "--concurrency", "1", "--queues", env["DCSEG_GPU_QUEUE"]]
    command += ["--loglevel", "info", "--without-gossip", "--without-mingle"]
    with log.open("wb") as output:
        process = subprocess.Popen(
            command,
            env={**env, **extra},
            cwd=REPO,
            stdout=output,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        try:
            yield process
        finally:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(process.pid, signal.SIGKILL)
            process.wait(10)


def _job(store: Store, job_id: str) -> Job:
    job = store.get_job(job_id)
    assert job is not None
    return job


@pytest.mark.integration
@pytest.mark.parametrize("pool", ["solo", "prefork"])
def test_sigterm_interrupts_the_celery_job_and_the_next_worker_resumes_it(
    celery_job, tmp_path, pool
):
    """Defect 2: "Celery mode has no SIGTERM hook: `docker compose stop worker` loses the
    running stage after the grace period"; the job must stop at its next progress report,
    keep its finished stages, not be acknowledged as done, and resume on the next worker."""
    env, store, job_id = celery_job
    first_log = tmp_path / "worker1.log"
    with _celery_worker(env, first_log, pool, DCSEG_TEST_SLOW_STEPS="1000") as first:

        def slow_running() -> bool:
            assert first.poll() is None, first_log.read_text()
            return "slow: step" in (_job(store, job_id).message or "")

        wait_for(slow_running, timeout=180, every=0.1)  # the worker starts slowly under load
        first.send_signal(signal.SIGTERM)
        try:  # 1000 steps take 100 s; the interrupted job ends at its next step
            first.wait(60)
        except subprocess.TimeoutExpired:
            pytest.fail(f"the worker kept running its job:\n{first_log.read_text()[-3000:]}")
    job = _job(store, job_id)
    # a shutdown is not a crash: the interrupted run gave its attempt back (max_attempts)
    assert job.status == "running" and job.attempts == 0, first_log.read_text()[-3000:]
    assert f"{job_id}] succeeded" not in first_log.read_text()
    paths = JobPaths(Path(env["DCSEG_STORAGE_DIR"]), job_id)
    assert [s["name"] for s in read_manifest(paths)["stages"]] == ["validate"]
    second_log = tmp_path / "worker2.log"
    with _celery_worker(env, second_log, pool, DCSEG_TEST_SLOW_STEPS="3") as second:

        def finished() -> bool:
            assert second.poll() is None, second_log.read_text()
            return _job(store, job_id).status in ("succeeded", "failed", "canceled")

        wait_for(finished, timeout=60, every=0.1)
    job = _job(store, job_id)
    assert job.status == "succeeded" and job.attempts == 1, second_log.read_text()[-3000:]
    messages = [e.data.get("message") for e in store.events_after(job_id, 0)]
    assert "validate: already finished" in messages


@pytest.mark.integration
def test_stage_that_never_reports_progress_is_killed_in_a_celery_prefork_child(
    celery_job, tmp_path
):
    """Defect 1 (Celery mode): a stage stuck without progress is stopped by killing the pool
    child; the job fails with the time-limit error and the worker stays up."""
    env, store, job_id = celery_job
    log = tmp_path / "worker.log"
    limits = {"DCSEG_STAGE_TIME_LIMIT_S": '{"stuck": 1}', "DCSEG_STAGE_KILL_GRACE_S": "1"}
    with _celery_worker(env, log, "prefork", DCSEG_TEST_STAGES="stuck_stages", **limits) as worker:

        def failed() -> bool:
            assert worker.poll() is None, log.read_text()
            return _job(store, job_id).status == "failed"

        wait_for(failed, timeout=90, every=0.1)
        error = _job(store, job_id).error
        assert error is not None and error["detail"] == _timeout_detail("stuck", "1")
        wait_for(lambda: "killing worker process" in log.read_text(), timeout=30)
        assert worker.poll() is None  # the main process stays up for the next job
