"""Gaussians <-> 3DGS PLY: exact round trips, the standard layout, extra columns, errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from plyfile import PlyData, PlyElement

from dcseg.errors import InputError
from dcseg.gaussians import Gaussians
from dcseg.io.ply import read_gaussians_ply, read_ply_extra, write_gaussians_ply


def random_gaussians(n: int, degree: int, seed: int = 0) -> Gaussians:
    g = torch.Generator().manual_seed(seed)
    k = (degree + 1) ** 2
    return Gaussians(
        means=torch.randn(n, 3, generator=g),
        quats=torch.randn(n, 4, generator=g),
        log_scales=torch.randn(n, 3, generator=g) - 3.0,
        opacity_logits=torch.randn(n, generator=g),
        sh=torch.randn(n, k, 3, generator=g),
    )


def assert_same(a: Gaussians, b: Gaussians) -> None:
    for name in ("means", "quats", "log_scales", "opacity_logits", "sh"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype == torch.float32, name
        assert torch.equal(x, y), name


@pytest.mark.parametrize("degree", [0, 1, 3])
def test_round_trip_is_exact(tmp_path: Path, degree: int) -> None:
    gaussians = random_gaussians(57, degree)
    path = tmp_path / "scene.ply"
    write_gaussians_ply(path, gaussians)
    back = read_gaussians_ply(path)
    assert back.sh_degree == degree
    assert_same(gaussians, back)


def test_layout_matches_3dgs(tmp_path: Path) -> None:
    gaussians = random_gaussians(5, 3)
    path = tmp_path / "scene.ply"
    write_gaussians_ply(path, gaussians)
    ply = PlyData.read(str(path))
    assert not ply.text and ply.byte_order == "<"
    names = [p.name for p in ply["vertex"].properties]
    expected = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    expected += [f"f_rest_{i}" for i in range(45)]
    expected += ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    assert names == expected
    data = ply["vertex"].data
    assert all(data.dtype[name] == np.dtype("<f4") for name in names)
    sh = gaussians.sh.numpy()
    # channel-major f_rest: the 15 R coefficients first, then G, then B
    np.testing.assert_array_equal(data["f_rest_0"], sh[:, 1, 0])
    np.testing.assert_array_equal(data["f_rest_14"], sh[:, 15, 0])
    np.testing.assert_array_equal(data["f_rest_15"], sh[:, 1, 1])
    np.testing.assert_array_equal(data["f_rest_44"], sh[:, 15, 2])
    np.testing.assert_array_equal(data["rot_0"], gaussians.quats[:, 0].numpy())
    np.testing.assert_array_equal(data["opacity"], gaussians.opacity_logits.numpy())


def test_extra_int_columns(tmp_path: Path) -> None:
    gaussians = random_gaussians(10, 0)
    instance = np.arange(10, dtype=np.int64) - 1
    semantic = np.full(10, 7, dtype=np.int32)
    path = tmp_path / "labelled.ply"
    write_gaussians_ply(path, gaussians, {"instance_id": instance, "semantic_id": semantic})
    data = PlyData.read(str(path))["vertex"].data
    assert data.dtype["instance_id"] == np.dtype("<i4")
    np.testing.assert_array_equal(data["instance_id"], instance)
    assert_same(gaussians, read_gaussians_ply(path))
    extra = read_ply_extra(path, "semantic_id")
    assert extra is not None
    np.testing.assert_array_equal(extra, semantic)
    assert read_ply_extra(path, "nothing") is None


def test_bad_extra_columns_are_rejected(tmp_path: Path) -> None:
    gaussians = random_gaussians(4, 0)
    with pytest.raises(ValueError, match="shape"):
        write_gaussians_ply(tmp_path / "a.ply", gaussians, {"id": np.zeros(3, np.int32)})
    with pytest.raises(ValueError, match="integer"):
        write_gaussians_ply(tmp_path / "a.ply", gaussians, {"id": np.zeros(4, np.float32)})
    with pytest.raises(ValueError, match="clashes"):
        write_gaussians_ply(tmp_path / "a.ply", gaussians, {"opacity": np.zeros(4, np.int32)})


def test_unknown_columns_are_ignored(tmp_path: Path) -> None:
    gaussians = random_gaussians(6, 0)
    path = tmp_path / "scene.ply"
    write_gaussians_ply(path, gaussians)
    data = PlyData.read(str(path))["vertex"].data
    extended = np.empty(len(data), dtype=[*data.dtype.descr, ("mask", "<f4")])
    for name in data.dtype.names:
        extended[name] = data[name]
    extended["mask"] = 1.0
    PlyData([PlyElement.describe(extended, "vertex")]).write(str(tmp_path / "saga.ply"))
    assert_same(gaussians, read_gaussians_ply(tmp_path / "saga.ply"))


def test_missing_property_names_file_and_property(tmp_path: Path) -> None:
    records = np.zeros(3, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("opacity", "<f4")])
    path = tmp_path / "points.ply"
    PlyData([PlyElement.describe(records, "vertex")]).write(str(path))
    with pytest.raises(InputError) as info:
        read_gaussians_ply(path)
    (problem,) = info.value.problems
    assert problem.path == str(path)
    assert "f_dc_0" in problem.reason and "rot_3" in problem.reason
    assert "'x'" not in problem.reason


def test_missing_and_garbage_files(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="not found"):
        read_gaussians_ply(tmp_path / "absent.ply")
    garbage = tmp_path / "garbage.ply"
    garbage.write_bytes(b"not a ply at all\n")
    with pytest.raises(InputError, match="garbage.ply"):
        read_gaussians_ply(garbage)


def test_bad_rest_count(tmp_path: Path) -> None:
    gaussians = random_gaussians(3, 1)
    path = tmp_path / "scene.ply"
    write_gaussians_ply(path, gaussians)
    data = PlyData.read(str(path))["vertex"].data
    keep = [name for name in data.dtype.names if name != "f_rest_8"]
    trimmed = np.empty(len(data), dtype=[(name, "<f4") for name in keep])
    for name in keep:
        trimmed[name] = data[name]
    PlyData([PlyElement.describe(trimmed, "vertex")]).write(str(tmp_path / "bad.ply"))
    with pytest.raises(InputError, match="f_rest"):
        read_gaussians_ply(tmp_path / "bad.ply")
