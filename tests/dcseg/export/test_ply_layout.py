"""PLY exports are the INRIA 3DGS layout byte for byte: read here as loaders that expect fixed
62-float records do (header parsed by hand, then one ``numpy.frombuffer``), not with our reader."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from dcseg.export import ExportOptions, export_run
from dcseg.io.splat_table import read_splat_table
from tests.dcseg.export.node_tools import splat_table_csv

INRIA = [
    *"x y z nx ny nz".split(),
    *(f"f_dc_{i}" for i in range(3)),
    *(f"f_rest_{i}" for i in range(45)),
    "opacity",
    *(f"scale_{i}" for i in range(3)),
    *(f"rot_{i}" for i in range(4)),
]


def read_fixed_records(path: Path) -> np.ndarray:
    """``[N, 62]`` float32 records of a binary little-endian PLY whose vertex element is
    exactly the INRIA property list (any other header fails the assertions)."""
    raw = path.read_bytes()
    end = raw.index(b"end_header\n") + len(b"end_header\n")
    lines = raw[:end].decode("ascii").splitlines()
    assert lines[:2] == ["ply", "format binary_little_endian 1.0"]
    elements = [line.split() for line in lines if line.startswith("element ")]
    assert len(elements) == 1 and elements[0][1] == "vertex"
    props = [line.split() for line in lines if line.startswith("property ")]
    assert [p[1] for p in props] == ["float"] * 62
    assert [p[2] for p in props] == INRIA
    n = int(elements[0][2])
    assert len(raw) - end == n * 62 * 4  # nothing after the records
    return np.frombuffer(raw, dtype="<f4", offset=end).reshape(n, 62)


@pytest.fixture(scope="module")
def out(run: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("inria")
    export_run(run, folder, "ply")
    return folder


def test_every_gaussian_ply_has_fixed_62_float_records(out: Path) -> None:
    names = [p.name for p in out.glob("*.ply") if p.name != "scene_labelled.ply"]
    assert {"scene.ply", "instance_1.ply", "scene_by_instance.ply"} <= set(names)
    for name in names:
        assert read_fixed_records(out / name).shape[1] == 62, name


def test_records_past_the_first_are_the_right_gaussians(run: Path, out: Path) -> None:
    source = read_splat_table(run / "scene_labelled.ply")
    ids = source.ints["instance_id"]
    records = read_fixed_records(out / "scene.ply")
    table = json.loads((out / "instances.ply.json").read_text())
    for record in table["instances"]:
        offset, count = record["gaussians"]
        assert offset > 0 or record is table["instances"][0]
        mine = records[offset : offset + count]
        part = source.take(ids == record["id"])  # same order within an object
        assert np.array_equal(mine[:, 0:3], part.means)
        assert np.all(mine[:, 3:6] == 0)
        assert np.array_equal(mine[:, 6:9], part.sh[:, 0])
        rest = mine[:, 9:54].reshape(count, 3, 15)  # channel-major, as the INRIA loader reads
        assert np.array_equal(rest[:, :, :3], part.sh[:, 1:4].transpose(0, 2, 1))
        assert np.all(rest[:, :, 3:] == 0)
        assert np.array_equal(mine[:, 54], part.opacity_logits)
        assert np.array_equal(mine[:, 55:58], part.log_scales)
        assert np.array_equal(mine[:, 58:62], part.quats)
    offset, count = table["unassigned_gaussians"]
    assert np.array_equal(records[offset:, 0:3], source.means[ids < 0])


def test_an_explicit_sh_degree_still_writes_floats_only(run: Path, tmp_path: Path) -> None:
    export_run(run, tmp_path, "ply", instances=[1], options=ExportOptions(sh_degree=0))
    header = (tmp_path / "instance_1.ply").read_bytes().split(b"end_header")[0].decode()
    props = [line.split() for line in header.splitlines() if line.startswith("property")]
    assert [p[2] for p in props] == [n for n in INRIA if not n.startswith("f_rest_")]
    assert {p[1] for p in props} == {"float"}


def test_splat_transform_reads_the_ply_as_written(out: Path, tmp_path: Path) -> None:
    """A second implementation (PlayCanvas splat-transform) reads the same Gaussians."""
    cols = splat_table_csv(out / "scene.ply", tmp_path / "scene.csv")
    records = read_fixed_records(out / "scene.ply")
    assert len(cols["x"]) == len(records)
    for i, name in enumerate(INRIA):
        if name in cols:
            assert np.allclose(cols[name], records[:, i], atol=1e-6), name
    assert sum(n.startswith("f_rest_") for n in cols) == 45
