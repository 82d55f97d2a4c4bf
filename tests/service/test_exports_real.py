"""The service's exports with the real ``dcseg.export`` on a finished run written in code (the
box-on-a-floor run of the exporter's own tests): files partition the labelled Gaussians,
options reach the exporter, a GLB holds one node per object; all through the HTTP API."""

from __future__ import annotations

import hashlib
import io
import json
import struct
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
from plyfile import PlyData

from service.main import create_app
from tests.scenes.runs import make_run
from tests.service.conftest import AUTH_A, TAR, StorageSettings, TestClient, assert_problem
from tests.service.segmented import run_segmented_job


@pytest.fixture(scope="module")
def run_files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, bytes]:
    run = make_run(tmp_path_factory.mktemp("run") / "run")
    return {p.relative_to(run).as_posix(): p.read_bytes() for p in run.rglob("*") if p.is_file()}


@pytest.fixture
def env(
    storage_settings: StorageSettings, scene_tar: bytes, run_files: dict[str, bytes]
) -> Iterator[tuple[TestClient, str]]:
    """A segmented job's service, its storage folder given as an absolute path or as the
    default's relative ``dcseg-data`` (resolved against the working directory)."""
    settings = storage_settings(export_wait_s=120.0)
    with TestClient(create_app(settings)) as client:
        upload = client.post("/v1/uploads", content=scene_tar, headers={**AUTH_A, **TAR}).json()
        yield client, run_segmented_job(client, upload["id"], files=run_files)


def _vertices(data: bytes) -> PlyData:
    return PlyData.read(io.BytesIO(data))["vertex"]


def _get(client: TestClient, url: str) -> dict[str, Any]:
    response = client.get(url, headers=AUTH_A)
    assert response.status_code == 200, response.text
    body: dict[str, Any] = response.json()
    return body


def test_ply_export_partitions_the_labelled_gaussians(env, run_files):
    client, job = env
    body = _get(client, f"/v1/jobs/{job}/exports/ply")
    by_name = {f["name"]: f for f in body["files"]}
    assert {"scene.ply", "frame.json", "instances.ply.json"} <= set(by_name)
    ids = np.asarray(_vertices(run_files["scene_labelled.ply"])["instance_id"])
    for k in (1, 2, 3):
        data = client.get(by_name[f"instance_{k}.ply"]["url"], headers=AUTH_A).content
        assert len(_vertices(data)) == int(np.sum(ids == k))
    record = client.get(f"/v1/jobs/{job}/instances/1", headers=AUTH_A).json()
    assert record["label"] == "box"


def test_sidecars_name_no_storage_path(env, tmp_path):
    client, job = env
    body = _get(client, f"/v1/jobs/{job}/exports/spz")
    sidecars = [f for f in body["files"] if f["name"].endswith(".json")]
    assert {"instances.spz.json", "frame.json"} <= {f["name"] for f in sidecars}
    for item in sidecars:
        data = client.get(item["url"], headers=AUTH_A)
        assert hashlib.sha256(data.content).hexdigest() == item["sha256"]
        assert str(tmp_path) not in data.text, item["name"]
    table = client.get(next(f["url"] for f in sidecars if f["name"] == "instances.spz.json"))
    assert table.status_code == 401  # downloads need the key like every route


def test_options_reach_the_exporter_and_are_cached_apart(env):
    client, job = env
    plain = _get(client, f"/v1/jobs/{job}/instances/2/exports/ply")
    dc_only = _get(client, f"/v1/jobs/{job}/instances/2/exports/ply?sh_degree=0")
    assert dc_only["options"] == {"sh_degree": 0} and plain["options"] == {}
    file = next(f for f in dc_only["files"] if f["name"] == "instance_2.ply")
    assert file["url"].endswith("/exports/ply/instance_2.ply?sh_degree=0")
    names = _vertices(client.get(file["url"], headers=AUTH_A).content).data.dtype.names
    assert sum(n.startswith("f_rest_") for n in names) == 0
    plain_file = next(f for f in plain["files"] if f["name"] == "instance_2.ply")
    plain_names = _vertices(client.get(plain_file["url"], headers=AUTH_A).content).data.dtype.names
    assert sum(n.startswith("f_rest_") for n in plain_names) == 45  # PLY's default: the INRIA SH 3
    coloured = _get(client, f"/v1/jobs/{job}/instances/2/exports/spz?colour=class")
    assert coloured["links"]["self"].endswith("/instances/2/exports/spz?colour=class")
    bad = client.get(f"/v1/jobs/{job}/exports/ply?sh_degree=4", headers=AUTH_A)
    assert [e["path"] for e in assert_problem(bad, 422)["errors"]] == ["query.sh_degree"]
    bad = client.get(f"/v1/jobs/{job}/exports/ply?colour=rainbow", headers=AUTH_A)
    assert [e["path"] for e in assert_problem(bad, 422)["errors"]] == ["query.colour"]


def test_splat_glb_of_one_object_has_its_node(env):
    client, job = env
    body = _get(client, f"/v1/jobs/{job}/instances/1/exports/glb")
    glb = next(f for f in body["files"] if f["name"].endswith(".glb"))
    assert glb["media_type"] == "model/gltf-binary"
    data = client.get(glb["url"], headers=AUTH_A).content
    (length,) = struct.unpack("<I", data[12:16])
    gltf = json.loads(data[20 : 20 + length])
    assert gltf["extensionsUsed"] == ["KHR_gaussian_splatting"]
    assert [(n["name"], n["extras"]["instance_id"]) for n in gltf["nodes"]] == [("box_1", 1)]


def test_mesh_glb_of_one_object_has_its_node(env):
    import trimesh

    client, job = env
    body = _get(client, f"/v1/jobs/{job}/instances/1/exports/glb-mesh")
    glb = next(f for f in body["files"] if f["name"].endswith(".glb"))
    assert glb["media_type"] == "model/gltf-binary"
    data = client.get(glb["url"], headers=AUTH_A).content
    scene = trimesh.load(io.BytesIO(data), file_type="glb", force="scene")
    assert isinstance(scene, trimesh.Scene)
    assert list(scene.geometry) == ["box_1"]  # the object's class and id name its node
    assert "box_1" in scene.graph.nodes_geometry


def test_usdz_of_one_object_is_served_as_usdz(env):
    client, job = env
    body = _get(client, f"/v1/jobs/{job}/instances/1/exports/usdz")
    usdz = next(f for f in body["files"] if f["name"].endswith(".usdz"))
    assert usdz["media_type"] == "model/vnd.usdz+zip"
    data = client.get(usdz["url"], headers=AUTH_A).content
    assert data[:2] == b"PK" and b"instance_1.usdc" in data[:200]  # a zip, .usdc root first
