"""Every kind of route, end to end, with the storage folder absolute and relative (the default
``./dcseg-data``, as ``dcseg serve`` in a checkout has it): upload, job submission, status,
events, artifact downloads, exports of the scene and of one object, instances, the viewer and
its ``frame.json``, readiness, and deleting the job and the upload."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

import pytest

from jobstore.contract import JobPaths
from service.main import create_app
from tests.scenes.runs import make_run
from tests.service.conftest import AUTH_A, TAR, StorageSettings, TestClient, state_of
from tests.worker.fakes import FakeStage
from worker.execute import execute_job

Files = dict[str, bytes]


@pytest.fixture(scope="module")
def run_files(tmp_path_factory: pytest.TempPathFactory) -> Files:
    """A finished run's files (poses with +z up), as a segment stage writes them."""
    run = make_run(tmp_path_factory.mktemp("run") / "run")
    return {p.relative_to(run).as_posix(): p.read_bytes() for p in run.rglob("*") if p.is_file()}


def ok(response: Any, status: int = 200) -> Any:
    assert response.status_code == status, response.text
    return response.json() if response.content else None


def submit_and_run(client: TestClient, scene_tar: bytes, files: Files) -> tuple[str, str]:
    """Upload, submit, run the job with a segment stage writing ``files``; (upload, job) ids."""
    upload = ok(client.post("/v1/uploads", content=scene_tar, headers={**AUTH_A, **TAR}), 201)
    assert ok(client.get(f"/v1/uploads/{upload['id']}", headers=AUTH_A))["id"] == upload["id"]
    job = ok(client.post("/v1/jobs", json={"upload_id": upload["id"]}, headers=AUTH_A), 202)
    state = state_of(client)
    stages = [FakeStage("segment", files=files, steps=2)]
    assert execute_job(job["id"], state.store, state.settings, stages=stages) == "succeeded"
    assert ok(client.get(f"/v1/jobs/{job['id']}", headers=AUTH_A))["status"] == "succeeded"
    return upload["id"], job["id"]


def check_events(client: TestClient, job_id: str) -> None:
    with client.stream("GET", f"/v1/jobs/{job_id}/events", headers=AUTH_A) as response:
        text = response.read().decode()
    assert response.status_code == 200
    assert "event: progress" in text and text.rstrip().split("\n\n")[-1].count("completed")


def check_artifacts(client: TestClient, job_id: str, files: Files) -> None:
    listing = ok(client.get(f"/v1/jobs/{job_id}/artifacts", headers=AUTH_A))["artifacts"]
    by_name = {a["name"]: a for a in listing}
    assert set(by_name) == {f"segment/{name}" for name in files}
    item = by_name["segment/instances.json"]
    whole = client.get(item["url"], headers=AUTH_A)
    assert whole.content == files["instances.json"]
    assert item["sha256"] == hashlib.sha256(whole.content).hexdigest()
    part = client.get(item["url"], headers={**AUTH_A, "Range": "bytes=2-9"})
    assert part.status_code == 206 and part.content == files["instances.json"][2:10]


def export_files(client: TestClient, url: str) -> dict[str, bytes]:
    """The files of the export at ``url`` (made now), downloaded and checked by SHA-256."""
    body = ok(client.get(url, headers=AUTH_A))
    out = {}
    for item in body["files"]:
        data = client.get(item["url"], headers=AUTH_A).content
        assert hashlib.sha256(data).hexdigest() == item["sha256"], item["name"]
        out[item["name"]] = data
    return out


def check_exports_and_instances(client: TestClient, job_id: str) -> None:
    scene = export_files(client, f"/v1/jobs/{job_id}/exports/glb")
    assert scene["scene.glb"][:4] == b"glTF"
    records = ok(client.get(f"/v1/jobs/{job_id}/instances", headers=AUTH_A))["instances"]
    k = records[0]["id"]
    assert ok(client.get(f"/v1/jobs/{job_id}/instances/{k}", headers=AUTH_A))["id"] == k
    one = export_files(client, f"/v1/jobs/{job_id}/instances/{k}/exports/ply")
    assert f"instance_{k}.ply" in one


def check_viewer(client: TestClient, job_id: str) -> None:
    page = client.get(f"/viewer/{job_id}")
    assert page.status_code == 200 and f"/viewer/{job_id}/frame.json" in page.text
    frame = ok(client.get(f"/viewer/{job_id}/frame.json", headers=AUTH_A))
    assert frame["world"]["up_axis"] == "+z"


def test_every_kind_of_route_with_this_storage_folder(
    storage_settings: StorageSettings, scene_tar: bytes, run_files: Files, tmp_path: Path
):
    settings = storage_settings(export_wait_s=120.0)
    with TestClient(create_app(settings)) as client:
        assert ok(client.get("/readyz"))["checks"]["storage"] == "ok"
        upload_id, job_id = submit_and_run(client, scene_tar, run_files)
        folder = JobPaths(settings.storage_dir, job_id).folder
        assert folder.is_dir() and folder.resolve().is_relative_to(tmp_path.resolve())
        check_events(client, job_id)
        check_artifacts(client, job_id, run_files)
        check_exports_and_instances(client, job_id)
        check_viewer(client, job_id)
        assert json.loads((folder / "output" / "manifest.json").read_text())  # where it says
        assert client.delete(f"/v1/jobs/{job_id}", headers=AUTH_A).status_code == 204
        assert not folder.exists()
        assert client.delete(f"/v1/uploads/{upload_id}", headers=AUTH_A).status_code == 204
        assert client.get(f"/v1/uploads/{upload_id}", headers=AUTH_A).status_code == 404
