"""Gaussian exports (PLY, SPZ, .splat): partition, palette colours, SH padding, round trips."""

from __future__ import annotations

import json
from pathlib import Path

import gsply
import numpy as np
import pytest
from plyfile import PlyData

from dcseg.export import ExportOptions, export_run
from dcseg.export.appearance import palette_colours
from dcseg.export.axes import gltf_turn, turned
from dcseg.export.splat_file import read_splat
from dcseg.io.splat_table import SH_C0, read_splat_table
from tests.scenes.runs import BOX, FLOOR_LEFT


def _sorted_rows(means: np.ndarray) -> np.ndarray:
    return means[np.lexsort(means.T[::-1])]


@pytest.fixture(scope="module")
def ply_out(run: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("ply")
    export_run(run, out, "ply")
    return out


def test_per_instance_plys_partition_the_labelled_gaussians(run: Path, ply_out: Path) -> None:
    source = read_splat_table(run / "scene_labelled.ply")
    ids = source.ints["instance_id"]
    table = json.loads((ply_out / "instances.ply.json").read_text())
    parts = []
    for record in table["instances"]:
        part = read_splat_table(ply_out / record["file"])
        assert part.ints == {}  # the INRIA layout: floats only
        assert len(part) == record["n_gaussians"] == int((ids == record["id"]).sum())
        assert np.array_equal(part.sh[:, :4], source.sh[ids == record["id"]])
        assert part.sh.shape[1] == 16 and np.all(part.sh[:, 4:] == 0)  # SH 3 by default
        parts.append(part.means)
    parts.append(source.means[ids < 0])
    assert np.array_equal(_sorted_rows(np.concatenate(parts)), _sorted_rows(source.means))


def test_scene_file_is_grouped_by_object_as_the_sidecar_says(run: Path, ply_out: Path) -> None:
    table = json.loads((ply_out / "instances.ply.json").read_text())
    scene = read_splat_table(ply_out / table["scene"])
    labelled = read_splat_table(ply_out / "scene_labelled.ply")  # the same order, ints kept
    assert len(scene) == len(labelled) == len(read_splat_table(run / "scene_labelled.ply"))
    assert np.array_equal(scene.means, labelled.means)
    labels = np.load(ply_out / table["labels"]["file"])
    assert table["labels"]["columns"] == ["instance_id", "semantic_id", "cluster_id"]
    assert labels.dtype == np.int32 and labels.shape == (len(scene), 3)
    for i, name in enumerate(table["labels"]["columns"]):
        assert np.array_equal(labels[:, i], labelled.ints[name])
    for record in table["instances"]:
        offset, count = record["gaussians"]
        assert np.all(labels[offset : offset + count, 0] == record["id"])
    offset, count = table["unassigned_gaussians"]
    assert offset + count == len(scene)
    assert np.all(labels[offset:, 0] == -1)


@pytest.mark.parametrize("mode", ["instance", "class"])
def test_palette_scene_has_the_palette_colour_in_its_dc_term(ply_out: Path, mode: str) -> None:
    table = json.loads((ply_out / "instances.ply.json").read_text())
    data = PlyData.read(str(ply_out / f"scene_by_{mode}.ply"))["vertex"].data
    rest = [n for n in data.dtype.names if n.startswith("f_rest_")]
    assert len(rest) == 45 and all(np.all(data[n] == 0) for n in rest)  # no view effects
    rgb = np.stack([0.5 + SH_C0 * data[f"f_dc_{c}"] for c in range(3)], axis=1) * 255
    key = "instance_id" if mode == "instance" else "semantic_id"
    column = table["labels"]["columns"].index(key)
    labels = np.load(ply_out / table["labels"]["file"])[:, column]
    if mode == "instance":
        expected = {r["id"]: r["rgb"] for r in table["instances"]}
    else:
        expected = {c["id"]: c["rgb"] for c in table["classes"]}
    for k, colour in expected.items():
        assert np.allclose(rgb[labels == k], colour, atol=0.01)
    assert np.allclose(rgb[labels == -1], 128, atol=0.01)


def test_palette_colours_are_distinct_and_none_is_grey() -> None:
    colours = palette_colours(np.array([1, 2, 3, -1, 99]), 1, 3)
    assert len({tuple(c) for c in colours[:3]}) == 3
    assert colours[3].tolist() == colours[4].tolist() == [128, 128, 128]


def test_sh_padding_gives_the_45_rest_coefficients_strict_loaders_need(
    run: Path, tmp_path: Path
) -> None:
    source = read_splat_table(run / "scene_labelled.ply")
    assert source.sh_degree == 1
    export_run(run, tmp_path, "ply", instances=[BOX], options=ExportOptions(sh_degree=3))
    data = PlyData.read(str(tmp_path / f"instance_{BOX}.ply"))["vertex"].data
    rest = [n for n in data.dtype.names if n.startswith("f_rest_")]
    assert rest == [f"f_rest_{i}" for i in range(45)]
    padded = read_splat_table(tmp_path / f"instance_{BOX}.ply")
    box = source.sh[source.ints["instance_id"] == BOX]
    assert np.array_equal(padded.sh[:, :4], box)
    assert np.all(padded.sh[:, 4:] == 0)


def test_sh_degree_zero_drops_the_higher_bands(run: Path, tmp_path: Path) -> None:
    export_run(run, tmp_path, "ply", instances=[BOX], options=ExportOptions(sh_degree=0))
    assert read_splat_table(tmp_path / f"instance_{BOX}.ply").sh.shape[1] == 1


def test_spz_read_back_with_gsply_equals_the_input_within_quantisation(
    run: Path, tmp_path: Path
) -> None:
    export_run(run, tmp_path, "spz", options=ExportOptions(sh_degree=3))
    source = read_splat_table(run / "scene_labelled.ply")
    turn = gltf_turn(run, None)
    table = json.loads((tmp_path / "instances.spz.json").read_text())
    for record in table["instances"]:
        back = gsply.read_spz(tmp_path / record["file"])
        part = turned(source.take(source.ints["instance_id"] == record["id"]), turn)  # RUB
        assert len(back) == len(part)
        assert np.abs(back.means - part.means).max() <= 0.5 / 4096 + 1e-6  # 12 fraction bits
        assert np.abs(back.sh0 - part.sh[:, 0]).max() <= 0.5 / (0.15 * 255) + 1e-4
        assert np.abs(back.shN[:, :3] - part.sh[:, 1:]).max() <= 0.5 / 128 + 1e-4
        assert np.all(back.shN[:, 3:] == 0)
        assert np.abs(back.scales - part.log_scales).max() <= 0.5 / 16 + 1e-6
        alpha = 1 / (1 + np.exp(-part.opacity_logits))
        assert np.abs(1 / (1 + np.exp(-back.opacities)) - alpha).max() <= 0.5 / 255 + 1e-3
        unit = part.quats / np.linalg.norm(part.quats, axis=1, keepdims=True)
        assert np.abs(np.abs(np.sum(back.quats * unit, axis=1)) - 1).max() < 1e-3
    scene = gsply.read_spz(tmp_path / "scene.spz")
    assert len(scene) == len(source)


def test_splat_records_hold_position_scale_colour_and_rotation(run: Path, tmp_path: Path) -> None:
    export_run(run, tmp_path, "splat", instances=[FLOOR_LEFT], options=ExportOptions())
    path = tmp_path / f"instance_{FLOOR_LEFT}.splat"
    records = read_splat(path)
    source = read_splat_table(run / "scene_labelled.ply")
    part = source.take(source.ints["instance_id"] == FLOOR_LEFT)
    assert path.stat().st_size == 32 * len(part)
    assert np.array_equal(records["position"], part.means)
    assert np.allclose(records["scale"], np.exp(part.log_scales))
    rgb = np.clip(0.5 + SH_C0 * part.sh[:, 0], 0, 1) * 255
    assert np.abs(records["rgba"][:, :3] - rgb).max() <= 0.5 + 1e-3
    alpha = 255 / (1 + np.exp(-part.opacity_logits))
    assert np.abs(records["rgba"][:, 3] - alpha).max() <= 0.5 + 1e-3
    unit = part.quats / np.linalg.norm(part.quats, axis=1, keepdims=True)
    decoded = (records["rotation"].astype(np.float64) - 128) / 128
    assert np.abs(decoded - unit).max() <= 1 / 128 + 1e-6


def test_colour_option_paints_per_object_files(run: Path, tmp_path: Path) -> None:
    export_run(run, tmp_path, "splat", instances=[BOX], options=ExportOptions(colour="instance"))
    table = json.loads((tmp_path / "instances.splat.json").read_text())
    rgba = read_splat(tmp_path / f"instance_{BOX}.splat")["rgba"]
    assert np.all(rgba[:, :3] == table["instances"][0]["rgb"])
