"""``/viewer/{job_id}/frame.json``: the up axis the API's viewer page starts with, found or
derived as ``dcseg view`` does (the job's own file, an export's, else the run's poses)."""

from __future__ import annotations

import json
from typing import Any

import numpy as np
import pytest

from dcseg.export.frame import describe_frame
from tests.dcseg.viewer.posed import Z_TO_Y
from tests.scenes.runs import make_run
from tests.service.conftest import AUTH_A, AUTH_B, TAR, assert_problem
from tests.service.segmented import run_segmented_job
from tests.worker.fakes import FakeStage
from worker.execute import execute_job

Files = dict[str, bytes]


@pytest.fixture(scope="module")
def z_up(tmp_path_factory: pytest.TempPathFactory) -> Files:
    """A finished run's files (``state/`` included) whose camera poses have +z up."""
    run = make_run(tmp_path_factory.mktemp("frame") / "run")
    return {p.relative_to(run).as_posix(): p.read_bytes() for p in run.rglob("*") if p.is_file()}


@pytest.fixture(scope="module")
def y_up(z_up: Files) -> Files:
    """The same run with every pose turned so that +z goes to +y (a y-up capture)."""
    views = json.loads(z_up["state/views.json"])
    for view in views["views"]:
        view["c2w"] = (Z_TO_Y @ np.asarray(view["c2w"])).tolist()
    return {**z_up, "state/views.json": json.dumps(views).encode()}


def poses_of(files: Files) -> np.ndarray:
    views = json.loads(files["state/views.json"])["views"]
    return np.stack([np.asarray(v["c2w"]) for v in views])


def served(client: Any, job_id: str) -> dict[str, Any]:
    response = client.get(f"/viewer/{job_id}/frame.json", headers=AUTH_A)
    assert response.status_code == 200, response.text
    assert response.headers["content-type"] == "application/json"
    assert response.headers["cache-control"] == "no-store"
    body: dict[str, Any] = response.json()
    return body


def test_a_y_up_and_a_z_up_job_are_served_different_up_axes(client, upload_id, z_up, y_up):
    frames = {}
    for name, files in (("z", z_up), ("y", y_up)):
        job_id = run_segmented_job(client, upload_id, files=files)
        frames[name] = served(client, job_id)
        assert frames[name] == describe_frame(poses_of(files), [])  # as the exports derive it
    assert frames["z"]["world"]["up_axis"] == "+z" and frames["z"]["world"]["up"] == [0, 0, 1]
    assert frames["y"]["world"]["up_axis"] == "+y" and frames["y"]["world"]["up"] == [0, 1, 0]


def test_the_page_names_the_frame_and_the_frame_needs_the_jobs_key(client, upload_id, z_up):
    job_id = run_segmented_job(client, upload_id, files=z_up)
    page = client.get(f"/viewer/{job_id}")
    config = json.loads(page.text.split('type="application/json">', 1)[1].split("</script>")[0])
    assert config["frame"] == f"/viewer/{job_id}/frame.json"
    assert_problem(client.get(config["frame"]), 401)
    assert_problem(client.get(config["frame"], headers=AUTH_B), 404)  # another tenant's job
    assert_problem(client.get("/viewer/not-a-job/frame.json", headers=AUTH_A), 404)
    running = client.post("/v1/jobs", json={"upload_id": upload_id}, headers=AUTH_A).json()
    assert_problem(client.get(f"/viewer/{running['id']}/frame.json", headers=AUTH_A), 409)


def test_a_job_without_a_segmented_scene_has_no_frame(client, upload_id):
    state = client.app.state.dcseg
    job_id = client.post("/v1/jobs", json={"upload_id": upload_id}, headers=AUTH_A).json()["id"]
    assert execute_job(job_id, state.store, state.settings, stages=[FakeStage("reconstruct")])
    body = assert_problem(client.get(f"/viewer/{job_id}/frame.json", headers=AUTH_A), 404)
    assert "no segmented scene" in body["detail"]


def export_frame(client: Any, job_id: str) -> dict[str, Any]:
    """Make the job's SPZ export through the API; returns the ``frame.json`` it wrote."""
    export = client.get(f"/v1/jobs/{job_id}/exports/spz", headers=AUTH_A)
    assert export.status_code == 200, export.text
    url = next(f["url"] for f in export.json()["files"] if f["name"] == "frame.json")
    body: dict[str, Any] = client.get(url, headers=AUTH_A).json()
    return body


@pytest.fixture
def export_client(make_client: Any) -> Any:
    return make_client(export_wait_s=120.0)


def test_the_jobs_own_frame_json_comes_first_even_after_an_export(export_client, scene_tar, y_up):
    client = export_client
    upload = client.post("/v1/uploads", content=scene_tar, headers={**AUTH_A, **TAR}).json()
    own = b'{"world": {"up_axis": "-x"}}'
    job_id = run_segmented_job(client, upload["id"], files={**y_up, "frame.json": own})
    assert export_frame(client, job_id)["world"]["up_axis"] == "+y"  # from the poses
    response = client.get(f"/viewer/{job_id}/frame.json", headers=AUTH_A)
    assert response.content == own


def test_an_exports_frame_json_is_served_once_the_export_exists(export_client, scene_tar, y_up):
    client = export_client
    upload = client.post("/v1/uploads", content=scene_tar, headers={**AUTH_A, **TAR}).json()
    job_id = run_segmented_job(client, upload["id"], files=y_up)
    derived = served(client, job_id)
    assert derived["to_gltf"]["applied_in"] == []  # derived here, as `dcseg view` derives it
    exported = export_frame(client, job_id)
    assert exported["to_gltf"]["applied_in"]  # the export's own file names where it applies
    assert served(client, job_id) == exported
    assert exported["world"] == derived["world"]
