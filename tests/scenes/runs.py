"""A finished run written in code: the analytic box-on-a-floor scene (:mod:`tests.scenes.analytic`),
its Gaussians back-projected from the depth and labelled by construction. numpy only (no torch):
the service's export tests use it too.

Objects: 1 = the box (class ``box``), 2 and 3 = the floor's halves x < 0 and x >= 0 (class
``floor``); floor Gaussians with |y| > 0.8 belong to no object. The run's ``state/`` holds the
views' depth and poses as a real run stores them.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from numpy.typing import NDArray

from dcseg.io.exports import instance_records, write_instances_json, write_labels_json
from dcseg.io.splat_table import SH_C0, SplatTable, write_splat_table
from dcseg.types import Capture, Vocabulary
from tests.scenes.analytic import BOX_HI, BOX_LO, make_capture

CLASSES = ("box", "floor")
BOX, FLOOR_LEFT, FLOOR_RIGHT = 1, 2, 3


def back_project(
    capture: Capture, stride: int = 2
) -> tuple[NDArray[np.float64], NDArray[np.uint8]]:
    """World points and colours of every ``stride``-th valid depth pixel of every frame."""
    points, colours = [], []
    for f in capture.frames:
        k = f.intrinsics
        v, u = np.mgrid[0 : k.height : stride, 0 : k.width : stride]
        z = f.depth[v, u]
        ok = z > 0
        cam = np.stack([(u - k.cx) / k.fx * z, (v - k.cy) / k.fy * z, z], axis=-1)[ok]
        points.append(cam @ f.c2w[:3, :3].T + f.c2w[:3, 3])
        colours.append(f.rgb[v, u][ok])
    return np.concatenate(points), np.concatenate(colours)


def object_ids(points: NDArray[np.float64]) -> tuple[NDArray[np.int32], NDArray[np.int32]]:
    """Object id and class index of each point (see the module docstring)."""
    on_box = np.all((points >= BOX_LO - 1e-3) & (points <= BOX_HI + 1e-3), axis=1)
    on_box &= points[:, 2] > 1e-3
    ids = np.where(points[:, 0] < 0, FLOOR_LEFT, FLOOR_RIGHT)
    ids = np.where(np.abs(points[:, 1]) > 0.8, -1, ids)
    ids = np.where(on_box, BOX, ids).astype(np.int32)
    classes = np.select([ids == BOX, ids > 0], [0, 1], -1).astype(np.int32)
    return ids, classes


def splats_of(
    points: NDArray[np.float64], rgb: NDArray[np.uint8], sh_degree: int, seed: int
) -> SplatTable:
    """Small isotropic Gaussians at ``points`` coloured ``rgb`` (random higher SH)."""
    rng = np.random.default_rng(seed)
    n = len(points)
    coeffs = (sh_degree + 1) ** 2
    sh = rng.normal(0.0, 0.05, (n, coeffs, 3)).astype(np.float32)
    sh[:, 0, :] = (rgb / 255.0 - 0.5) / SH_C0
    ids, classes = object_ids(points)
    return SplatTable(
        means=points.astype(np.float32),
        quats=rng.normal(size=(n, 4)).astype(np.float32),
        log_scales=np.full((n, 3), np.log(0.01), np.float32),
        opacity_logits=rng.normal(2.0, 0.5, n).astype(np.float32),
        sh=sh,
        ints={"instance_id": ids, "semantic_id": classes, "cluster_id": ids.copy()},
    )


def write_state(run: Path, capture: Capture) -> None:
    """``state/views.json`` and ``state/views/<i>.npz`` (depth as float16) as a run has them."""
    folder = run / "state" / "views"
    folder.mkdir(parents=True)
    meta = []
    for i, f in enumerate(capture.frames):
        k = f.intrinsics
        K = [[k.fx, 0.0, k.cx], [0.0, k.fy, k.cy], [0.0, 0.0, 1.0]]
        meta.append({"name": f.name, "width": k.width, "height": k.height, "K": K,
                     "c2w": f.c2w.tolist()})  # fmt: skip
        np.savez(folder / f"{i}.npz", depth=f.depth.astype(np.float16))
    body = {"version": 1, "views": meta}
    (run / "state" / "views.json").write_text(json.dumps(body), encoding="utf-8")


def write_objects(
    run: Path,
    ply: Path,
    means: NDArray[np.floating],
    cluster: NDArray[np.integer],
    classes: NDArray[np.integer],
    vocabulary: Vocabulary,
) -> None:
    """``instances.json`` and ``labels.json`` of three objects: cluster ``k`` is object ``k + 1``
    of class ``classes[k]`` (scores 0.9, 0.8, 0.7; seen in 5, 4, 3 views)."""
    scores, views = np.array([0.9, 0.8, 0.7]), np.array([5, 4, 3])
    records = instance_records(means, cluster, classes, scores, views, vocabulary)
    write_instances_json(run / "instances.json", records, ply)
    write_labels_json(run / "labels.json", vocabulary)


def make_run(
    run: Path, frames: int = 8, size: tuple[int, int] = (64, 48), sh_degree: int = 1, seed: int = 0
) -> Path:
    """Write a finished run folder at ``run`` and return it."""
    capture = make_capture(frames, *size)
    points, rgb = back_project(capture)
    splats = splats_of(points, rgb, sh_degree, seed)
    run.mkdir(parents=True)
    ply = run / "scene_labelled.ply"
    write_splat_table(ply, splats)
    ids = splats.ints["instance_id"]
    cluster = np.where(ids > 0, ids - 1, -1)
    write_objects(run, ply, points, cluster, np.array([0, 1, 1]), Vocabulary(CLASSES))
    write_state(run, capture)
    record = {"inputs": {"capture": str(run.parent / "no-such-capture")}, "counts": {}}
    (run / "run.json").write_text(json.dumps(record), encoding="utf-8")
    return run


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One finished run per test module (a conftest imports it to use it)."""
    return make_run(tmp_path_factory.mktemp("export") / "run")
