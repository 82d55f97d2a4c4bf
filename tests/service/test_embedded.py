"""Embedded mode: ``dcseg serve`` without a broker runs jobs itself and resumes after restarts."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from datetime import timedelta
from pathlib import Path

import httpx
import pytest

from dcseg.cli import main
from dcseg.cli import serve as served
from dcseg.client import ApiError, Client
from jobstore.store import Store
from service.main import create_app
from tests.service.conftest import (
    AUTH_A,
    KEY_A,
    TAR,
    TestClient,
    free_port,
    make_settings,
    state_of,
    stop_process,
    tar_bytes,
    wait_for,
)

TINY = {
    "reconstruct": {"iterations": 3, "holdout": 0},
    "affinity": {"iterations": 5, "rays": 64},
}


@pytest.fixture
def serve(tmp_path: Path) -> Iterator[str]:
    """``dcseg serve`` in a child process, with its default embedded worker; yields its URL.
    Its storage folder is the default, the relative ``./dcseg-data``, in ``tmp_path`` (as a
    user's first ``dcseg serve`` has it; every other service test gives an absolute one)."""
    port = free_port()
    env = {
        **os.environ,
        "DCSEG_API_KEYS": f"tenant-a:{KEY_A}",
        "DCSEG_POLL_INTERVAL_S": "0.1",
        "DCSEG_DEVICE": "cpu",
    }
    env.pop("DCSEG_DATABASE_URL", None)
    env.pop("DCSEG_BROKER_URL", None)
    env.pop("DCSEG_STORAGE_DIR", None)
    log = (tmp_path / "serve.log").open("wb")
    command = [
        sys.executable,
        "-m",
        "dcseg",
        "serve",
        "--port",
        str(port),
        "--log-level",
        "warning",
    ]
    process = subprocess.Popen(command, env=env, cwd=tmp_path, stdout=log, stderr=subprocess.STDOUT)
    url = f"http://127.0.0.1:{port}"

    def up() -> bool:
        assert process.poll() is None, (tmp_path / "serve.log").read_text()
        try:
            return httpx.get(f"{url}/readyz", timeout=1).status_code == 200
        except httpx.TransportError:
            return False

    try:
        wait_for(up, timeout=60, every=0.1)
        yield url
        assert (tmp_path / "dcseg-data" / "jobs").is_dir()  # where the default says
    finally:
        stop_process(process, signal.SIGINT, 20)
        log.close()


def test_one_command_runs_a_job_end_to_end(serve, scene, tmp_path, capsys):
    archive = tmp_path / "scene.tar"
    archive.write_bytes(tar_bytes(scene))
    connection = ["--url", serve, "--api-key", KEY_A]
    options = json.dumps(TINY)
    assert main(["submit", str(archive), "--options", options, *connection]) == 0
    job_id = capsys.readouterr().out.strip()
    assert main(["wait", job_id, "--timeout", "120", *connection]) == 0
    assert capsys.readouterr().out.strip() == f"{job_id} succeeded"
    assert main(["download", job_id, str(tmp_path / "out"), "--all", *connection]) == 0
    files = capsys.readouterr().out.split()
    names = sorted(Path(f).relative_to(tmp_path / "out").as_posix() for f in files)
    expected = {
        "validate/report.json",
        "reconstruct/reconstruction.json",
        "reconstruct/scene.ply",
        "segment/scene_labelled.ply",
        "segment/instances.json",
        "segment/labels.json",
        "segment/metrics.json",
        "segment/preview.png",
        "segment/run.json",
        "segment/state/affinity.npz",
    }
    assert expected <= set(names), names
    assert any(n.startswith("segment/masks/") for n in names)
    assert (tmp_path / "out" / "reconstruct" / "scene.ply").read_bytes().startswith(b"ply")
    instances = json.loads((tmp_path / "out" / "segment" / "instances.json").read_text())
    assert instances["instances"], "the pipeline found no instance"
    with Client(serve, KEY_A) as client:
        check_exports_and_viewer(client, serve, job_id, tmp_path / "exports")
        upload_id = client.status(job_id)["upload_id"]
        with pytest.raises(ApiError) as refused:  # refused at submission, nothing queued
            client.submit(upload_id, options={"reconstruct": {"no_such_knob": 1}})
    assert refused.value.status == 422
    errors = refused.value.problem["errors"]
    assert errors[0]["path"] == "body.options.reconstruct.no_such_knob"


def check_exports_and_viewer(client: Client, url: str, job_id: str, dest: Path) -> None:
    """The scene's PLY and one object's GLB are made and downloaded (SHA-256 checked); the
    viewer's frame.json is served (the routes a relative storage folder once broke)."""
    ply = client.download_export(job_id, "ply", dest / "scene", only=["scene.ply"])
    assert [p.name for p in ply] == ["scene.ply"] and ply[0].read_bytes().startswith(b"ply")
    k = client.instances(job_id)[0]["id"]
    glb = client.download_export(job_id, "glb", dest / "one", instance=k, only=["*.glb"])
    assert [p.name for p in glb] == [f"instance_{k}.glb"]
    assert glb[0].read_bytes()[:4] == b"glTF"
    frame = httpx.get(f"{url}/viewer/{job_id}/frame.json", headers=AUTH_A, timeout=30)
    assert frame.status_code == 200 and "up_axis" in frame.json()["world"]


def test_startup_sweep_requeues_unfinished_jobs(tmp_path, scene_tar):
    settings = make_settings(tmp_path)
    with TestClient(create_app(settings)) as client:
        upload = client.post("/v1/uploads", content=scene_tar, headers={**AUTH_A, **TAR}).json()
        job_id = client.post("/v1/jobs", json={"upload_id": upload["id"]}, headers=AUTH_A).json()[
            "id"
        ]
        store: Store = state_of(client).store
        assert store.claim_job(job_id, "crashed-worker", timedelta(seconds=60)) is not None
    with TestClient(create_app(settings)) as client:
        job = client.get(f"/v1/jobs/{job_id}", headers=AUTH_A).json()
        assert job["status"] == "queued"
        assert job["progress"]["message"] == "requeued at startup"


def test_thread_worker_picks_up_queued_jobs(tmp_path, scene_tar):
    """``dcseg serve``'s app (:func:`dcseg.cli.serve.create_app`) runs the embedded worker."""
    settings = make_settings(tmp_path, embedded_worker="thread")
    with TestClient(served.create_app(settings)) as client:
        upload = client.post("/v1/uploads", content=scene_tar, headers={**AUTH_A, **TAR}).json()
        body = {
            "upload_id": upload["id"],
            "options": {
                "reconstruct": {"iterations": 1, "holdout": 0},
                "affinity": {"iterations": 5, "rays": 64},
            },
        }
        job_id = client.post("/v1/jobs", json=body, headers=AUTH_A).json()["id"]

        def finished():
            job = client.get(f"/v1/jobs/{job_id}", headers=AUTH_A).json()
            return job if job["status"] in ("succeeded", "failed") else None

        job = wait_for(finished, timeout=120, every=0.2)
        assert job["status"] == "succeeded", job
        started = time.monotonic()
    assert time.monotonic() - started < 15, "shutdown must not hang"


def test_abandoned_temporary_uploads_are_removed_at_startup(tmp_path):
    settings = make_settings(tmp_path)
    old = settings.storage_dir / "uploads" / ".tmp-old"
    recent = settings.storage_dir / "uploads" / ".tmp-recent"
    for folder in (old, recent):
        folder.mkdir(parents=True)
    os.utime(old, (time.time() - 2 * 86400, time.time() - 2 * 86400))
    with TestClient(create_app(settings)):
        pass
    assert not old.exists() and recent.exists()
