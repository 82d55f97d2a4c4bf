"""``glb`` loaded by an engine: the PlayCanvas engine's own glTF parser (2.23.3, its
``KHR_gaussian_splatting`` extension, on a null graphics device) turns every node of our GLB
into the Gaussians the run holds, in glTF's Y-up, with nothing of our reader involved."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from dcseg.export import export_run
from dcseg.export.axes import gltf_turn, turned
from dcseg.io.splat_table import SplatTable, read_splat_table
from tests.dcseg.export.node_tools import playcanvas_glb

ATOL = 1e-6


@pytest.fixture(scope="module")
def glb(run: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("glb")
    export_run(run, out, "glb")
    return out


def in_position_order(columns: dict[str, Any]) -> dict[str, np.ndarray]:
    """The engine's columns sorted by position (it reorders Gaussians in Morton order)."""
    values = {name: np.asarray(v, np.float64) for name, v in columns.items()}
    order = np.lexsort((values["z"], values["y"], values["x"]))
    return {name: v[order] for name, v in values.items()}


def assert_loaded_as(splats: dict[str, Any], expected: SplatTable) -> None:
    """The engine's Gaussians of one node are ``expected`` (already turned to glTF's axes)."""
    assert splats["activated"] and splats["count"] == len(expected)
    got = in_position_order(splats["columns"])
    order = np.lexsort(expected.means.T[::-1])
    part = expected.take(order)
    xyz = np.stack([got["x"], got["y"], got["z"]], axis=1)
    assert np.abs(xyz - part.means).max() <= ATOL
    scales = np.stack([got[f"scale_{i}"] for i in range(3)], axis=1)
    assert np.allclose(scales, np.exp(part.log_scales), rtol=1e-6)  # linear, as stored
    alpha = 1 / (1 + np.exp(-part.opacity_logits.astype(np.float64)))
    assert np.abs(got["opacity"] - alpha).max() <= ATOL
    quats = np.stack([got[f"rot_{i}"] for i in range(4)], axis=1)  # w x y z
    unit = part.quats / np.linalg.norm(part.quats, axis=1, keepdims=True)
    assert np.abs(np.abs(np.sum(quats * unit, axis=1)) - 1).max() <= ATOL
    degree_1 = part.sh.shape[1] - 1  # coefficients past the DC term
    for c in range(3):
        assert np.abs(got[f"f_dc_{c}"] - part.sh[:, 0, c]).max() <= ATOL
        for k in range(degree_1):  # channel-major, as PLY's f_rest_*
            assert np.abs(got[f"f_rest_{c * degree_1 + k}"] - part.sh[:, 1 + k, c]).max() <= ATOL
    assert sum(name.startswith("f_rest_") for name in got) == 3 * degree_1


def test_the_playcanvas_engine_loads_each_node_as_its_objects_gaussians(
    run: Path, glb: Path
) -> None:
    source = read_splat_table(run / "scene_labelled.ply")
    ids, turn = source.ints["instance_id"], gltf_turn(run, None)
    table = json.loads((glb / "instances.glb.json").read_text())
    (scene,) = playcanvas_glb(glb / "scene.glb")
    nodes = {node["name"]: node["splats"] for node in scene["nodes"]}
    assert list(nodes) == [r["node"] for r in table["instances"]] + ["unassigned"]
    for record in table["instances"]:
        (splats,) = nodes[record["node"]]
        assert_loaded_as(splats, turned(source.take(ids == record["id"]), turn))
    (rest,) = nodes["unassigned"]
    assert_loaded_as(rest, turned(source.take(ids < 0), turn))


def test_the_playcanvas_engine_loads_every_object_file(run: Path, glb: Path) -> None:
    source = read_splat_table(run / "scene_labelled.ply")
    ids, turn = source.ints["instance_id"], gltf_turn(run, None)
    records = json.loads((glb / "instances.glb.json").read_text())["instances"]
    loaded = playcanvas_glb(*(glb / r["file"] for r in records))
    for record, file in zip(records, loaded, strict=True):
        ((node, splats),) = [(n["name"], n["splats"]) for n in file["nodes"]]
        assert node == record["node"] and len(splats) == 1
        assert_loaded_as(splats[0], turned(source.take(ids == record["id"]), turn))
