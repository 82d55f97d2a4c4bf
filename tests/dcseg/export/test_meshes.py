"""Meshes fused from the run's depth: GLB nodes per object, labels, frame, decimation, OBJ/PLY."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import trimesh
from plyfile import PlyData

from dcseg.errors import InputError
from dcseg.export import ExportOptions, export_run
from dcseg.export.depth import run_views
from dcseg.export.surface import extract
from dcseg.export.tsdf import fuse
from dcseg.io.captures.manifest import write_capture
from tests.dcseg.export.node_tools import gltf_validate
from tests.scenes.analytic import BOX_HI, make_capture, surface_distance
from tests.scenes.runs import BOX, CLASSES, FLOOR_LEFT, FLOOR_RIGHT

OPTIONS = ExportOptions(voxel_size=0.025, max_faces=1500)
Y_UP = np.array([[1, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1]], np.float64)


@pytest.fixture(scope="module")
def glb(run: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("glb")
    export_run(run, out, "glb-mesh", options=OPTIONS)
    return out / "scene_mesh.glb"


def test_tsdf_surface_lies_on_the_scene_and_faces_the_cameras(run: Path) -> None:
    views = run_views(run)
    assert views is not None
    volume = fuse(views, voxel=0.025)
    vertices, faces = extract(volume)
    assert len(faces) > 1000
    assert np.median(surface_distance(vertices)) < 0.01
    assert np.percentile(surface_distance(vertices), 95) < 0.025
    normals = trimesh.Trimesh(vertices, faces, process=False).face_normals
    floor = vertices[faces].mean(axis=1)[:, 2] < 0.005
    assert np.mean(normals[floor, 2] > 0.9) > 0.9  # the floor's normals point up, at the cameras


def test_glb_has_one_node_per_object_with_its_class_and_score(run: Path, glb: Path) -> None:
    scene = trimesh.load_scene(glb)
    nodes = sorted(scene.graph.nodes_geometry)
    assert nodes == ["box_1", "floor_2", "floor_3"]
    records = {r["id"]: r for r in json.loads((run / "instances.json").read_text())["instances"]}
    for node in nodes:
        extras = scene.graph.transforms.edge_data[(scene.graph.base_frame, node)]["metadata"]
        record = records[extras["instance_id"]]
        assert extras["class"] == record["label"] == CLASSES[extras["class_id"]]
        assert extras["score"] == pytest.approx(record["score"])
        assert extras["name"] == node
    table = json.loads((glb.parent / "instances.glb-mesh.json").read_text())
    assert sorted(r["node"] for r in table["instances"]) == nodes


def test_the_khronos_validator_finds_no_error_warning_or_info(glb: Path) -> None:
    """gltf-validator 2.0.0-dev.3.10: only hints, and only BUFFER_VIEW_TARGET_MISSING (trimesh,
    which writes the file, sets no ``bufferView.target``; optional in glTF 2.0)."""
    (report,) = gltf_validate(glb)
    issues = report["issues"]
    assert (issues["numErrors"], issues["numWarnings"], issues["numInfos"]) == (0, 0, 0), issues
    assert {m["code"] for m in issues["messages"]} <= {"BUFFER_VIEW_TARGET_MISSING"}


def test_glb_nodes_are_turned_to_y_up_and_meshes_decimated(glb: Path) -> None:
    scene = trimesh.load_scene(glb)
    for node in scene.graph.nodes_geometry:
        matrix, geometry = scene.graph[node]
        assert np.allclose(matrix, Y_UP)
        mesh = scene.geometry[geometry]
        assert 0 < len(mesh.faces) <= OPTIONS.max_faces
        assert mesh.visual.vertex_colors.shape == (len(mesh.vertices), 4)
    box = scene.geometry["box_1"]
    up = (Y_UP[:3, :3] @ box.vertices.T).T  # what a Y-up viewer shows
    assert up[:, 1].max() == pytest.approx(BOX_HI[2], abs=0.03)
    assert up[:, 1].min() > -0.03


def test_object_meshes_follow_the_labelled_gaussians(run: Path, tmp_path: Path) -> None:
    export_run(run, tmp_path, "obj", options=OPTIONS)
    box = trimesh.load_mesh(tmp_path / f"instance_{BOX}.obj", process=False)
    left = trimesh.load_mesh(tmp_path / f"instance_{FLOOR_LEFT}.obj", process=False)
    right = trimesh.load_mesh(tmp_path / f"instance_{FLOOR_RIGHT}.obj", process=False)
    assert np.mean(box.vertices[:, 2] > 0.01) > 0.9
    assert np.mean(left.vertices[:, 0] < 0.03) > 0.95
    assert np.mean(right.vertices[:, 0] > -0.03) > 0.95
    assert np.abs(left.vertices[:, 1]).max() < 0.8 + 0.1  # |y| > 0.8 belongs to no object
    ply = PlyData.read(str(tmp_path / "scene_mesh.ply"))
    ids = ply["vertex"]["instance_id"]
    assert sorted(set(ids.tolist())) == [BOX, FLOOR_LEFT, FLOOR_RIGHT]
    assert len(ply["face"]) == len(box.faces) + len(left.faces) + len(right.faces)


def test_palette_colours_reach_the_mesh(run: Path, tmp_path: Path) -> None:
    options = ExportOptions(voxel_size=0.025, max_faces=1500, colour="class")
    export_run(run, tmp_path, "obj", instances=[FLOOR_LEFT], options=options)
    table = json.loads((tmp_path / "instances.obj.json").read_text())
    colour = table["classes"][1]["rgb"]
    mesh = trimesh.load_mesh(tmp_path / f"instance_{FLOOR_LEFT}.obj", process=False)
    assert isinstance(mesh.visual, trimesh.visual.ColorVisuals)
    assert np.all(mesh.visual.vertex_colors[:, :3] == colour)
    assert table["instances"][0]["file"] == f"instance_{FLOOR_LEFT}.obj"


def test_a_run_without_depth_asks_for_the_capture(run: Path, tmp_path: Path) -> None:
    bare = tmp_path / "bare"
    shutil.copytree(run, bare)
    shutil.rmtree(bare / "state")
    with pytest.raises(InputError, match="holds no depth.*is gone; give the capture.*--capture"):
        export_run(bare, tmp_path / "out", "glb-mesh", options=OPTIONS)
    assert list((tmp_path / "out").iterdir()) == []  # no partial files, no staging folder
    export_run(bare, tmp_path / "out", "ply")  # Gaussian formats need no depth


def test_a_run_without_depth_is_meshed_from_its_capture(run: Path, tmp_path: Path) -> None:
    bare = tmp_path / "bare"
    shutil.copytree(run, bare)
    shutil.rmtree(bare / "state")
    capture = tmp_path / "capture"
    write_capture(make_capture(8, 64, 48), capture)
    options = ExportOptions(voxel_size=0.025, max_faces=1500, capture=capture)
    export_run(bare, tmp_path / "out", "glb-mesh", options=options)
    scene = trimesh.load_scene(tmp_path / "out" / "scene_mesh.glb")
    assert sorted(scene.graph.nodes_geometry) == ["box_1", "floor_2", "floor_3"]
    frame = json.loads((tmp_path / "out" / "frame.json").read_text())
    assert frame["world"]["up_axis"] == "+z"  # poses from the capture too


def test_a_grid_over_the_voxel_limit_is_refused(run: Path, tmp_path: Path) -> None:
    with pytest.raises(InputError, match="^voxel_size: .*give a larger --voxel-size"):
        export_run(run, tmp_path, "glb-mesh", options=ExportOptions(voxel_size=0.0005))
