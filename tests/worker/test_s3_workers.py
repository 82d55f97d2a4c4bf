"""Workers without a shared disk: API + PostgreSQL + Redis + a real S3 server + two
``dcseg worker`` processes, each with a private scratch folder.

A job runs the real pipeline with its artifacts only in the bucket; the worker running it is
killed mid-stage and the other finishes from the last committed stage; every artifact matches
its manifest's SHA-256, presigned downloads work and expire. Needs Redis
(``DCSEG_TEST_REDIS``), PostgreSQL (``DCSEG_TEST_POSTGRES``) and the ``weed`` binary; skipped
with the reason when one is missing. Timeouts are generous: a loaded 2-core machine.
"""

from __future__ import annotations

import hashlib
import os
import signal
import subprocess
import sys
import time
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import IO, Any

import httpx
import pytest

from jobstore.s3 import S3Storage
from service.main import create_app
from tests.s3server import S3Server, s3_settings
from tests.service.conftest import (
    AUTH_A,
    TAR,
    TestClient,
    state_of,
    stop_process,
    tar_bytes,
    wait_for,
)
from tests.service.test_databases import postgres_server  # noqa: F401 (fixture)
from tests.worker.conftest import REPO
from tests.worker.test_celery_integration import REDIS_URL, _forget_queue, _redis_reachable

pytestmark = pytest.mark.integration

TERMINAL = ("succeeded", "failed", "canceled")
HEARTBEAT_S = 2.0
"""Stale after 6 s: a loaded machine importing torch must not look like a dead worker."""


@pytest.fixture
def stack(
    s3_server: S3Server,
    postgres_server: str,  # noqa: F811
    tmp_path: Path,
) -> Iterator[tuple[Any, dict[str, str]]]:
    """The API's settings and the workers' environment: S3 storage, PostgreSQL, Redis."""
    if not _redis_reachable():
        pytest.skip(f"Redis not reachable at {REDIS_URL}")
    queue = f"gpu-s3-test-{uuid.uuid4().hex[:8]}"
    settings = s3_settings(
        s3_server,
        tmp_path / "api",
        broker_url=REDIS_URL,
        database_url=postgres_server,
        gpu_queue=queue,
        heartbeat_s=HEARTBEAT_S,
        sweep_interval_s=1.0,
        presign_expiry_s=60,
    )
    env = {
        **os.environ,
        **s3_server.env(settings.s3_bucket),
        "DCSEG_BROKER_URL": REDIS_URL,
        "DCSEG_DATABASE_URL": postgres_server,
        "DCSEG_GPU_QUEUE": queue,
        "DCSEG_DEVICE": "cpu",
        "DCSEG_HEARTBEAT_S": str(HEARTBEAT_S),
        "OMP_NUM_THREADS": "1",
    }
    try:
        yield settings, env
    finally:
        _forget_queue(queue)


@pytest.fixture
def start_worker(
    stack: tuple[Any, dict[str, str]], tmp_path: Path
) -> Iterator[Callable[[str], subprocess.Popen[bytes]]]:
    """``start_worker(name)``: a ``dcseg worker --pool solo`` with its own scratch folder
    ``tmp_path/<name>/scratch`` and working directory (no shared disk with the API)."""
    _, env = stack
    started: list[tuple[subprocess.Popen[bytes], IO[bytes]]] = []

    def start(name: str) -> subprocess.Popen[bytes]:
        home = tmp_path / name
        home.mkdir()
        worker_env = {
            **env,
            "DCSEG_SCRATCH_DIR": str(home / "scratch"),
            "DCSEG_STORAGE_DIR": str(home / "unused"),
            "PYTHONPATH": str(REPO),
        }
        log = (tmp_path / f"{name}.log").open("wb")
        command = [sys.executable, "-m", "dcseg", "worker", "--pool", "solo", "--loglevel", "info"]
        process = subprocess.Popen(
            command, env=worker_env, cwd=home, stdout=log, stderr=subprocess.STDOUT
        )
        started.append((process, log))
        return process

    try:
        yield start
    finally:
        for process, log in started:
            if process.poll() is None:
                stop_process(process, signal.SIGTERM, 20)
            log.close()


def _logs(tmp_path: Path) -> str:
    return "\n".join(p.read_text(errors="replace")[-3000:] for p in tmp_path.glob("*.log"))


def _job(client: TestClient, job_id: str) -> dict[str, Any]:
    body: dict[str, Any] = client.get(f"/v1/jobs/{job_id}", headers=AUTH_A).json()
    return body


def test_two_workers_without_a_shared_disk_resume_a_killed_job(
    stack, start_worker, scene, tmp_path
):
    settings, _ = stack
    first = start_worker("worker-a")
    with TestClient(create_app(settings)) as client:
        upload = client.post("/v1/uploads", content=tar_bytes(scene), headers={**AUTH_A, **TAR})
        assert upload.status_code == 201, upload.text
        body = {
            "upload_id": upload.json()["id"],
            "options": {
                "reconstruct": {"iterations": 60, "holdout": 0},
                "affinity": {"iterations": 5, "rays": 64},
            },
        }
        job_id = client.post("/v1/jobs", json=body, headers=AUTH_A).json()["id"]

        def reconstructing() -> bool:
            assert first.poll() is None, _logs(tmp_path)
            return "reconstruct: step" in (_job(client, job_id)["progress"]["message"] or "")

        wait_for(reconstructing, timeout=240, every=0.1)
        state = state_of(client)
        storage = state.storage
        assert isinstance(storage, S3Storage)
        committed = [s["name"] for s in storage.manifest("tenant-a", job_id)["stages"]]
        assert committed == ["validate"]  # the last committed stage when the worker dies
        first.kill()
        first.wait(10)
        start_worker("worker-b")

        def finished() -> dict[str, Any] | None:
            job = _job(client, job_id)
            return job if job["status"] in TERMINAL else None

        job = wait_for(finished, timeout=600, every=0.5)
        assert job["status"] == "succeeded", (job, _logs(tmp_path))
        record = state.store.get_job(job_id)
        assert record is not None and record.attempts == 2
        messages = [e.data.get("message") for e in state.store.events_after(job_id, 0)]
        assert "validate: already finished" in messages

        # artifacts only in the bucket, each matching its manifest's SHA-256
        manifest = storage.manifest("tenant-a", job_id)
        names = [s["name"] for s in manifest["stages"]]
        assert names == ["validate", "reconstruct", "train", "segment"]
        listing = client.get(f"/v1/jobs/{job_id}/artifacts", headers=AUTH_A).json()["artifacts"]
        assert "reconstruct/scene.ply" in [a["name"] for a in listing]
        for item in listing:
            direct = httpx.get(item["download_url"], timeout=60)
            assert direct.status_code == 200, item["name"]
            assert hashlib.sha256(direct.content).hexdigest() == item["sha256"]
        scene_ply = next(a for a in listing if a["name"] == "reconstruct/scene.ply")
        proxied = client.get(scene_ply["url"], headers=AUTH_A)
        assert hashlib.sha256(proxied.content).hexdigest() == scene_ply["sha256"]
        assert not (settings.storage_dir / "jobs").exists()  # nothing on the API's disk
        for name in ("worker-a", "worker-b"):
            assert not (tmp_path / name / "unused" / "jobs").exists()
        assert not (tmp_path / "worker-b" / "scratch" / job_id).exists()  # cleaned

        # the killed worker's attempt left objects of its own: never named by the manifest
        keys = {o["Key"] for o in storage.objects(storage.key("tenant-a", f"jobs/{job_id}/"))}
        named = {
            storage.key("tenant-a", f["key"])
            for s in manifest["stages"]
            for f in s["files"].values()
        }
        assert named <= keys
        attempts = {k.split("/attempts/")[1].split("/")[0] for k in named}
        assert len(attempts) == 2  # validate by worker A, the rest by worker B

        # presigned URLs expire (a short expiry, against the same bucket)
        short = S3Storage(storage.client, storage.bucket, storage.prefix, storage.presigner, 1)
        url = short.presign("tenant-a", storage.files("tenant-a", job_id)[0])
        assert url is not None
        deadline = time.monotonic() + 60
        while httpx.get(url).status_code == 200:
            assert time.monotonic() < deadline, "the presigned URL never expired"
            time.sleep(0.5)
        assert httpx.get(url).status_code == 403
