""".splat exports read back by an independent implementation, PlayCanvas splat-transform's
``.splat`` reader (antimatter15's 32-byte records), not by ``dcseg.export.splat_file``: every
Gaussian of the scene and of each object file is the run's, within the format's 8-bit
quantisation, in world coordinates and grouped by object as the sidecar says."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from dcseg.export import export_run
from dcseg.io.splat_table import SH_C0, SplatTable, read_splat_table
from tests.dcseg.export.node_tools import splat_table_csv

Columns = dict[str, np.ndarray]
BYTE = 1 / 255
"""One step of the format's 8-bit colour, opacity and rotation components."""
ROTATION_DEGREES = 2.5
"""8-bit quaternion components: half a step of rounding plus the two decoders' half-step
offset (``(r - 128) / 128`` in antimatter15's viewer, ``r / 127.5 - 1`` in splat-transform):
at most ~1.8 degrees between the rotations (1.5 measured on the test run)."""


@pytest.fixture(scope="module")
def out(run: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("splat")
    export_run(run, folder, "splat")
    return folder


def sigmoid(x: np.ndarray) -> np.ndarray:
    return np.asarray(1 / (1 + np.exp(-x)))


def assert_same_gaussians(theirs: Columns, start: int, part: SplatTable) -> None:
    """Rows ``start...`` of splat-transform's columns are ``part``'s Gaussians, in order."""
    rows = slice(start, start + len(part))
    xyz = np.stack([theirs[c][rows] for c in ("x", "y", "z")], axis=1)
    assert np.array_equal(xyz.astype(np.float32), part.means)  # float32, no axis turn
    scales = np.stack([theirs[f"scale_{i}"][rows] for i in range(3)], axis=1)
    assert np.allclose(scales, part.log_scales, atol=1e-5)  # linear in the file
    dc = np.stack([theirs[f"f_dc_{i}"][rows] for i in range(3)], axis=1)
    rgb = np.clip(0.5 + SH_C0 * part.sh[:, 0], 0, 1)
    assert np.abs(0.5 + SH_C0 * dc - rgb).max() <= BYTE / 2 + 1e-6
    alpha = sigmoid(theirs["opacity"][rows])
    assert np.abs(alpha - sigmoid(part.opacity_logits)).max() <= BYTE / 2 + 1e-6
    quats = np.stack([theirs[f"rot_{i}"][rows] for i in range(4)], axis=1)
    unit = part.quats / np.linalg.norm(part.quats, axis=1, keepdims=True)
    angle = 2 * np.arccos(np.minimum(np.sum(quats * unit, axis=1), 1.0))  # w, x, y, z
    assert np.degrees(angle).max() <= ROTATION_DEGREES


def test_splat_transform_reads_the_scene_grouped_by_object(
    run: Path, out: Path, tmp_path: Path
) -> None:
    source = read_splat_table(run / "scene_labelled.ply")
    ids = source.ints["instance_id"]
    table = json.loads((out / "instances.splat.json").read_text())
    theirs = splat_table_csv(out / table["scene"], tmp_path / "scene.csv")
    assert len(theirs["x"]) == len(source) == (out / table["scene"]).stat().st_size // 32
    for record in table["instances"]:
        offset, count = record["gaussians"]
        assert count == int((ids == record["id"]).sum()) > 0
        assert_same_gaussians(theirs, offset, source.take(ids == record["id"]))
    offset, count = table["unassigned_gaussians"]
    assert offset + count == len(source)
    assert_same_gaussians(theirs, offset, source.take(ids < 0))


def test_splat_transform_reads_every_object_file(run: Path, out: Path, tmp_path: Path) -> None:
    source = read_splat_table(run / "scene_labelled.ply")
    records = json.loads((out / "instances.splat.json").read_text())["instances"]
    assert len(records) >= 2
    for record in records:
        theirs = splat_table_csv(out / record["file"], tmp_path / f"{record['id']}.csv")
        part = source.take(source.ints["instance_id"] == record["id"])
        assert len(theirs["x"]) == len(part)
        assert_same_gaussians(theirs, 0, part)
