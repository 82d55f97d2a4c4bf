"""The stand-in masks for timing real captures: regions of one colour become masks."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from benchmarks.superpixel_bundle import make_bundle, regions
from dcseg.io.masks import read_agnostic_masks
from dcseg.io.semantic import read_semantic_maps, read_vocabulary
from dcseg.jobs import RunInputs
from tests.dcseg.io.layouts import make_scene, write_replica


def test_regions_split_colours_and_drop_specks() -> None:
    rgb = np.zeros((40, 60, 3), dtype=np.uint8)
    rgb[:, 30:] = (250, 10, 10)  # a second colour: a second region
    rgb[5, 5] = (10, 250, 10)  # one pixel: below the minimum share
    out = regions(rgb, 3)
    assert len(np.unique(out[out > 0])) == 2
    assert out[5, 5] == 0
    assert out[0, 0] != out[0, 59]


def test_bundle_of_a_replica_capture_reads_as_a_run_input(tmp_path: Path) -> None:
    rgbd_scene = make_scene()
    capture = write_replica(rgbd_scene, tmp_path / "capture", cam_params=False)
    k = rgbd_scene.k
    count = make_bundle(capture, tmp_path / "bundle", (k.fx, k.fy, k.cx, k.cy))
    assert count == rgbd_scene.n
    inputs = RunInputs.from_bundle(tmp_path / "bundle")
    assert inputs.agnostic_masks and inputs.vocabulary and inputs.semantic_masks
    size = (k.width, k.height)
    agnostic = read_agnostic_masks(inputs.agnostic_masks, size=size)
    assert set(agnostic) == {f"frame{i:06d}" for i in range(rgbd_scene.n)}
    assert all(len(m) > 0 for m in agnostic.values())
    vocabulary = read_vocabulary(inputs.vocabulary)
    semantic = read_semantic_maps(inputs.semantic_masks, vocabulary, size=size)
    assert all(m.classes.shape == (k.height, k.width) for m in semantic.values())
