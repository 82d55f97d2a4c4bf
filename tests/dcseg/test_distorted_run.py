"""A ``dcseg synth`` scene seen through a lens with distortion (images, depth and masks all
distorted with COLMAP's own camera model, pycolmap), written as a COLMAP ``OPENCV`` model, runs
end to end: the frames and the masks made on the distorted images are undistorted alike."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pycolmap
import pytest
from numpy.typing import NDArray

from dcseg.cli import main
from dcseg.config import JobConfig, preset
from dcseg.io.captures import read_capture
from dcseg.io.images import read_image
from dcseg.io.masks import decode_masks, masks_from_dense, read_agnostic_masks, write_agnostic_json
from dcseg.io.run_output import load_run
from dcseg.io.semantic import read_semantic_maps, read_vocabulary, write_semantic_png
from dcseg.jobs import RunInputs, evaluate_job, run_job
from dcseg.lens import of_record, remap_nearest
from dcseg.types import Intrinsics, SemanticMap
from tests.dcseg.io.layouts import RgbdScene
from tests.dcseg.io.test_captures_colmap import write_colmap

pytest.importorskip("pybullet", reason="the synthetic scene generator needs pybullet")

DISTORTION = [0.2, 0.05, 0.001, -0.001]  # OPENCV k1 k2 p1 p2: pincushion, ~10 px at the corners


def lens_params(k: Intrinsics) -> list[float]:
    return [k.fx, k.fy, k.cx + 0.5, k.cy + 0.5, *DISTORTION]


def source_pixels(k: Intrinsics) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Per pixel of the distorted image, where its ray meets the pinhole image (COLMAP)."""
    camera = pycolmap.Camera(model="OPENCV", width=k.width, height=k.height, params=lens_params(k))
    v, u = np.mgrid[0 : k.height, 0 : k.width].astype(np.float64)
    pixels = np.stack([u.ravel(), v.ravel()], axis=1) + 0.5  # COLMAP's pixel centres
    rays = camera.cam_from_img(pixels)
    assert rays is not None
    x = (rays[:, 0] * k.fx + k.cx).reshape(u.shape).astype(np.float32)
    y = (rays[:, 1] * k.fy + k.cy).reshape(u.shape).astype(np.float32)
    return x, y


def distort(image: NDArray[Any], k: Intrinsics, nearest: bool) -> NDArray[Any]:
    x, y = source_pixels(k)
    if nearest:
        rows = np.clip(np.floor(y + 0.5), 0, k.height - 1).astype(np.int64)
        cols = np.clip(np.floor(x + 0.5), 0, k.width - 1).astype(np.int64)
        return np.ascontiguousarray(image[rows, cols])
    return np.asarray(cv2.remap(image, x, y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE))


def distorted_inputs(scene: Path, out: Path) -> RunInputs:
    """The synth scene through the lens: a COLMAP model with depth, and the masks."""
    capture = read_capture(scene)
    k = capture.frames[0].intrinsics
    rgbd = RgbdScene(
        [distort(f.rgb, k, nearest=False) for f in capture.frames],
        [distort(f.depth, k, nearest=True) for f in capture.frames],
        [f.c2w for f in capture.frames],
        k,
    )
    cameras = {1: ("OPENCV", k.width, k.height, lens_params(k))}
    root = write_colmap(rgbd, out / "colmap", cameras=cameras)
    names = [f"frame_{i}" for i in range(len(capture))]  # write_colmap's names
    agnostic = read_agnostic_masks(scene / "masks" / "agnostic")
    vocabulary = read_vocabulary(scene / "vocabulary.txt")
    semantic = read_semantic_maps(scene / "masks" / "semantic", vocabulary)
    for name, frame in zip(names, capture.frames, strict=True):
        dense = np.stack([distort(m, k, nearest=True) for m in decode_masks(agnostic[frame.name])])
        write_agnostic_json(out / "agnostic" / f"{name}.json", masks_from_dense(name, dense))
        classes = distort(np.asarray(semantic[frame.name].classes), k, nearest=True)
        path = out / "semantic" / f"{name}.png"
        write_semantic_png(path, SemanticMap(name, classes), len(vocabulary))
    return RunInputs(
        capture=root,
        agnostic_masks=out / "agnostic",
        semantic_masks=out / "semantic",
        vocabulary=scene / "vocabulary.txt",
        ground_truth=scene / "gt" / "points.ply",
    )


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    root = tmp_path_factory.mktemp("distorted")
    scene = root / "scene"
    args = ["synth", str(scene), "--frames", "6", "--size", "160x120", "--noise", "clean"]
    assert main([*args, "--supersample", "1"]) == 0
    cfg = preset("fast")
    cfg = replace(
        cfg,
        reconstruct=replace(cfg.reconstruct, iterations=150, holdout=3),
        affinity=replace(cfg.affinity, iterations=60, rays=256),
    )
    run_job(distorted_inputs(scene, root), JobConfig(cfg), root / "run")
    return scene, root / "run"


def test_the_run_records_the_undistortion(runs: tuple[Path, Path]) -> None:
    _, run = runs
    record = json.loads((run / "run.json").read_text())
    (entry,) = record["capture"]["undistortion"]
    assert entry["model"] == "opencv" and entry["coefficients"] == DISTORTION
    assert sorted(entry["frames"]) == [f"frame_{i}" for i in range(6)]
    assert record["reconstruction"]["undistortion"] == record["capture"]["undistortion"]
    assert record["metrics_summary"]["dcseg_projection"]["miou"] > 0.2


def test_masks_are_undistorted_with_their_frames(runs: tuple[Path, Path]) -> None:
    """The class maps the run kept are the synth scene's own (pinhole) maps seen through the
    run's pinhole camera: the masks were undistorted like the images. Left distorted, they
    would disagree along every object edge."""
    scene, run = runs
    saved = load_run(run)
    vocabulary = read_vocabulary(scene / "vocabulary.txt")
    truth = read_semantic_maps(scene / "masks" / "semantic", vocabulary)
    original = read_capture(scene).frames[0].intrinsics
    agree, distorted_agree = [], []
    for view in saved.trained.views:
        pinhole = np.asarray(truth[f"frame_{int(view.name[6:]):04d}"].classes)  # synth's name
        expected = resample(pinhole, view.K, original)
        kept = np.asarray(saved.semantic[view.name].classes)
        agree.append(float((kept == expected).mean()))
        distorted = distort(pinhole, original, nearest=True)
        distorted_agree.append(float((distorted == expected).mean()))
    assert len(agree) == 6
    assert min(agree) > 0.97
    assert max(distorted_agree) < min(agree) - 0.02


def resample(classes: NDArray[Any], k_new: NDArray[Any], k: Intrinsics) -> NDArray[Any]:
    """A pinhole class map of ``k`` seen through the pinhole camera ``k_new`` (same size)."""
    v, u = np.mgrid[0 : k.height, 0 : k.width].astype(np.float64)
    x = (u - k_new[0, 2]) / k_new[0, 0] * k.fx + k.cx
    y = (v - k_new[1, 2]) / k_new[1, 1] * k.fy + k.cy
    rows = np.clip(np.floor(y + 0.5), 0, k.height - 1).astype(np.int64)
    cols = np.clip(np.floor(x + 0.5), 0, k.width - 1).astype(np.int64)
    return np.asarray(classes[rows, cols])


def test_label_maps_overlay_the_distorted_images(runs: tuple[Path, Path]) -> None:
    """``labels/`` is written onto the capture's own (distorted) pixels: it agrees with the
    distorted class masks given better than it would left in the undistorted camera; and read
    back (``evaluate_job``), it scores what the run scored."""
    scene, run = runs
    vocabulary = read_vocabulary(scene / "vocabulary.txt")
    given = read_semantic_maps(run.parent / "semantic", vocabulary)
    lenses = of_record(json.loads((run / "run.json").read_text()))
    direct, left_undistorted = [], []
    for name, u in lenses.items():
        labels = read_image(run / "labels" / f"{name}.png").astype(np.int64) - 1
        truth = np.asarray(given[name].classes)
        labelled = labels >= 0
        direct.append(float((labels == truth)[labelled].mean()))
        undistorted = remap_nearest(labels, u)
        left_undistorted.append(float((undistorted == truth)[undistorted >= 0].mean()))
    assert len(direct) == 6
    assert np.mean(direct) > np.mean(left_undistorted) + 0.02, (direct, left_undistorted)
    metrics = json.loads((run / "metrics.json").read_text())
    again = evaluate_job(run, scene / "gt" / "points.ply")
    projection = again["dcseg_projection"]["miou"]
    assert projection == pytest.approx(metrics["dcseg_projection"]["miou"], abs=0.02)
