"""``obj`` read back by hand, not by the libraries that write it (trimesh writes the OBJs,
plyfile ``scene_mesh.ply``): an OBJ parser of the ``v x y z r g b`` / ``f i j k`` lines and a
binary PLY parser of the header the format promises; each object's OBJ equals its rows of
``scene_mesh.ply`` (vertices, colours, triangles) and together they are the whole PLY."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from dcseg.export import ExportOptions, export_run

OPTIONS = ExportOptions(voxel_size=0.025, max_faces=1500)
PLY_HEADER = [
    "ply",
    "format binary_little_endian 1.0",
    "property float x",
    "property float y",
    "property float z",
    "property uchar red",
    "property uchar green",
    "property uchar blue",
    "property int instance_id",
    "property list uchar int vertex_indices",
    "end_header",
]
VERTEX = np.dtype(
    [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("rgb", "u1", 3), ("instance_id", "<i4")]
)
FACE = np.dtype([("n", "u1"), ("v", "<i4", 3)])


@pytest.fixture(scope="module")
def out(run: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("obj")
    export_run(run, folder, "obj", options=OPTIONS)
    return folder


def read_obj(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertices ``[V, 3]``, colours ``[V, 3]`` in 0..1 and 0-based triangles ``[F, 3]``."""
    vertices, faces = [], []
    for line in path.read_text(encoding="ascii").splitlines():
        if not line.strip():
            continue
        kind, *values = line.split()
        if kind == "v":
            assert len(values) == 6, line  # position and colour
            vertices.append([float(v) for v in values])
        elif kind == "f":
            assert len(values) == 3, line  # triangles, vertex indices only
            faces.append([int(v) - 1 for v in values])
        else:
            assert kind == "#", line
    table = np.asarray(vertices)
    return table[:, :3], table[:, 3:], np.asarray(faces)


def read_mesh_ply(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """The vertex records and the 0-based triangles ``[F, 3]`` of ``scene_mesh.ply``."""
    raw = path.read_bytes()
    end = raw.index(b"end_header\n") + len(b"end_header\n")
    lines = raw[:end].decode("ascii").splitlines()
    counts = {line.split()[1]: int(line.split()[2]) for line in lines if line.startswith("element")}
    assert [line for line in lines if not line.startswith("element")] == PLY_HEADER
    n, f = counts["vertex"], counts["face"]
    assert len(raw) - end == n * VERTEX.itemsize + f * FACE.itemsize  # nothing else
    vertex = np.frombuffer(raw, VERTEX, n, end)
    face = np.frombuffer(raw, FACE, f, end + n * VERTEX.itemsize)
    assert np.all(face["n"] == 3)
    return vertex, face["v"]


def test_each_objects_obj_is_its_part_of_the_scene_ply(out: Path) -> None:
    vertex, faces = read_mesh_ply(out / "scene_mesh.ply")
    table = json.loads((out / "instances.obj.json").read_text())
    start, n_faces = 0, 0
    for record in table["instances"]:
        xyz, rgb, triangles = read_obj(out / record["file"])
        rows = vertex[start : start + len(xyz)]
        assert np.all(rows["instance_id"] == record["id"]) and len(triangles) > 0
        ply_xyz = np.stack([rows["x"], rows["y"], rows["z"]], axis=1)
        assert np.abs(xyz - ply_xyz).max() <= 1e-7  # 8 decimals in the OBJ, float32 in the PLY
        assert np.abs(rgb * 255 - rows["rgb"]).max() <= 1e-4
        ply_triangles = faces[n_faces : n_faces + len(triangles)]
        assert np.array_equal(triangles + start, ply_triangles)
        start, n_faces = start + len(xyz), n_faces + len(triangles)
    assert (start, n_faces) == (len(vertex), len(faces))  # the objects are the whole PLY
