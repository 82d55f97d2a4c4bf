"""Redis restarts without persistence: queued jobs are re-sent, connected workers reconnect.

A private ``redis-server --save "" --appendonly no`` on a free port (skipped when
``redis-server`` is not on PATH) is killed and started again, so it comes back empty: every
queued message and the broker's bookkeeping are gone. The API (a ``TestClient``) stays up the
whole time and real ``dcseg worker --pool solo`` processes run the jobs.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import redis

from jobstore.contract import TERMINAL, JobPaths
from service.main import create_app
from service.queue import marker_key
from tests.service.conftest import (
    AUTH_A,
    TAR,
    TestClient,
    free_port,
    make_settings,
    state_of,
    tar_bytes,
    wait_for,
)
from tests.worker.conftest import worker_log, worker_processes

QUEUE = "gpu"
TINY = {"reconstruct": {"iterations": 2, "holdout": 0}, "affinity": {"iterations": 5, "rays": 64}}

pytestmark = pytest.mark.integration


class PrivateRedis:
    """A ``redis-server`` subprocess without persistence; ``restart()`` loses all its data."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.port = free_port()
        self.url = f"redis://127.0.0.1:{self.port}/0"
        self.process: subprocess.Popen[bytes] | None = None
        self.client = redis.Redis(port=self.port, socket_timeout=2)

    def start(self) -> None:
        command = ["redis-server", "--port", str(self.port), "--bind", "127.0.0.1"]
        command += ["--save", "", "--appendonly", "no", "--dir", str(self.folder)]
        self.process = subprocess.Popen(
            command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
        )
        wait_for(self._answers, timeout=10)

    def _answers(self) -> bool:
        try:
            return bool(self.client.ping())
        except redis.ConnectionError:
            return False

    def kill(self) -> None:
        if self.process is not None and self.process.poll() is None:
            self.process.kill()
            self.process.wait(10)

    def restart(self) -> None:
        """SIGKILL and start again on the same port: a new server, with no data (nothing was
        saved). The API may write to it at once, so its emptiness is not asserted here."""
        before = self.client.info("server")["run_id"]
        self.kill()
        self.start()
        assert self.client.info("server")["run_id"] != before


@pytest.fixture
def private_redis(tmp_path: Path) -> Iterator[PrivateRedis]:
    if shutil.which("redis-server") is None:
        pytest.skip("redis-server is not on PATH")
    server = PrivateRedis(tmp_path)
    server.start()
    yield server
    server.kill()
    server.client.close()


@pytest.fixture
def start_worker(
    private_redis: PrivateRedis, tmp_path: Path
) -> Iterator[Callable[[], subprocess.Popen[bytes]]]:
    """Starts ``dcseg worker --pool solo`` on the private Redis; stops it after the test."""
    env = {
        **os.environ,
        "DCSEG_BROKER_URL": private_redis.url,
        "DCSEG_STORAGE_DIR": str(tmp_path / "data"),
        "DCSEG_DATABASE_URL": f"sqlite:///{tmp_path / 'data' / 'dcseg.db'}",
        "DCSEG_GPU_QUEUE": QUEUE,
        "DCSEG_DEVICE": "cpu",
        "DCSEG_HEARTBEAT_S": "0.5",
    }
    with worker_processes(env, tmp_path) as start:
        yield start


def _submit(client: Any, upload_id: str, options: dict[str, Any]) -> str:
    body = {"upload_id": upload_id, "options": options}
    response = client.post("/v1/jobs", json=body, headers=AUTH_A)
    assert response.status_code == 202, response.text
    job_id: str = response.json()["id"]
    return job_id


def _queued_ids(server: PrivateRedis) -> list[str]:
    """Job ids of the messages waiting in the queue (each message's ``argsrepr``)."""
    messages = [json.loads(m) for m in server.client.lrange(QUEUE, 0, -1)]
    return sorted(m["headers"]["argsrepr"].strip("[]'") for m in messages)


def _assert_succeeded_with_intact_artifacts(client: Any, job_id: str, root: Path) -> None:
    job = client.get(f"/v1/jobs/{job_id}", headers=AUTH_A).json()
    assert job["status"] == "succeeded", job
    listing = client.get(f"/v1/jobs/{job_id}/artifacts", headers=AUTH_A).json()["artifacts"]
    names = [a["name"] for a in listing]
    assert {"reconstruct/scene.ply", "segment/instances.json"} <= set(names)
    assert len(names) == len(set(names))
    for item in listing:
        data = client.get(item["url"], headers=AUTH_A).content
        assert len(data) == item["size"]
        assert hashlib.sha256(data).hexdigest() == item["sha256"]
    assert not list(JobPaths(root, job_id).output.glob(".tmp-*"))


def test_redis_restarts_lose_no_job(private_redis, start_worker, scene, tmp_path):
    """1. Two jobs are queued and Redis restarts empty before any worker runs: the API (still
    up) notices the broker lost its data and re-sends both; a worker started afterwards runs
    both to success. 2. Redis restarts while that worker is connected and running a third
    job: the job still succeeds, and the worker reconnects and runs a fourth job submitted
    after the restart. Every job runs exactly once and its artifacts match the manifest."""
    settings = make_settings(
        tmp_path,
        broker_url=private_redis.url,
        gpu_queue=QUEUE,
        heartbeat_s=1.5,
        sweep_interval_s=0.3,
    )
    with TestClient(create_app(settings)) as client:
        assert client.get("/readyz").json()["checks"]["broker"] == "ok"
        upload = client.post("/v1/uploads", content=tar_bytes(scene), headers={**AUTH_A, **TAR})
        upload_id = upload.json()["id"]
        first = sorted(_submit(client, upload_id, TINY) for _ in range(2))
        assert _queued_ids(private_redis) == first

        private_redis.restart()  # the queued messages are gone; the API sends them again
        assert wait_for(lambda: _queued_ids(private_redis) == first, timeout=20)

        worker = start_worker()

        def ended(job_ids: list[str]) -> Callable[[], bool]:
            def check() -> bool:
                assert worker.poll() is None, worker_log(tmp_path)
                jobs = [client.get(f"/v1/jobs/{j}", headers=AUTH_A).json() for j in job_ids]
                return all(job["status"] in TERMINAL for job in jobs)

            return check

        wait_for(ended(first), timeout=180, every=0.25)
        for job_id in first:
            _assert_succeeded_with_intact_artifacts(client, job_id, settings.storage_dir)

        slow = {**TINY, "reconstruct": {"iterations": 150, "holdout": 0}}
        third = _submit(client, upload_id, slow)

        def training() -> bool:
            job = client.get(f"/v1/jobs/{third}", headers=AUTH_A).json()
            assert job["status"] not in TERMINAL, job
            return "step" in (job["progress"]["message"] or "")

        wait_for(training, timeout=60, every=0.05)
        private_redis.restart()  # the worker's connection drops mid-job
        assert client.get(f"/v1/jobs/{third}", headers=AUTH_A).json()["status"] == "running"
        time.sleep(1.0)
        fourth = _submit(client, upload_id, TINY)
        wait_for(ended([third, fourth]), timeout=180, every=0.25)
        assert worker.poll() is None, worker_log(tmp_path)
        assert "Connection to broker lost" in worker_log(tmp_path, tail=0)  # it reconnected
        for job_id in (third, fourth):
            _assert_succeeded_with_intact_artifacts(client, job_id, settings.storage_dir)

        store = state_of(client).store
        for job_id in [*first, third, fourth]:
            record = store.get_job(job_id)
            assert record is not None and record.attempts == 1, (job_id, worker_log(tmp_path))
        assert private_redis.client.exists(marker_key(QUEUE))
