"""error_model_stats: per object, the share of views whose class map names it right."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from benchmarks.error_model_stats import scene_stats
from dcseg.io.ground_truth import write_ground_truth_ply
from dcseg.types import GroundTruth


def _write(path: Path, image: np.ndarray) -> None:
    import cv2

    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), image)


def _write_points(path: Path, classes: dict[int, int]) -> None:
    """Ten ground-truth points per instance id, labelled with its class."""
    ids = np.repeat(np.array(sorted(classes), dtype=np.int64), 10)
    labels = np.array([classes[int(i)] for i in ids], dtype=np.int64)
    points = np.random.default_rng(0).normal(size=(len(ids), 3))
    write_ground_truth_ply(path, GroundTruth(points, labels, ids))


def test_objects_wrong_in_every_view_and_by_majority(tmp_path: Path) -> None:
    vocabulary = ["wall", "floor", "table", "mug", "cup"]
    instances = [
        {"id": 1, "class": "floor", "kind": "structure"},
        {"id": 2, "class": "table", "kind": "furniture"},
        {"id": 3, "class": "mug", "kind": "object"},
    ]
    made = {"vocabulary": vocabulary, "instances": instances, "error_model": "lowres"}
    (tmp_path / "scene.json").write_text(json.dumps(made))
    ids = np.ones((20, 20), dtype=np.uint16)
    ids[0:10], ids[12:18, 12:18] = 2, 3
    for i, mug_class in enumerate((4, 4, 3)):  # the mug is a cup in 2 of 3 views
        classes = np.where(ids == 2, 2, 1).astype(np.uint8)
        classes[ids == 3] = mug_class
        _write(tmp_path / "gt" / "instance" / f"f{i}.png", ids)
        _write(tmp_path / "masks" / "semantic" / f"f{i}.png", classes)
    _write_points(tmp_path / "gt" / "points.ply", {1: 1, 2: 2, 3: 3})
    stats = scene_stats(tmp_path, min_pixels=20)
    assert stats["objects"] == 2 and stats["error_model"] == "lowres"  # the floor is not one
    assert stats["majority_wrong"] == 0.5 and stats["wrong_in_every_view"] == 0.0
    assert stats["right_in_every_view"] == 0.5  # the table
    mug = next(r for r in stats["per_object"] if r["id"] == 3)
    assert mug["right_share"] == 0.333 and mug["top"] == 4
    # bounds with perfect geometry: the majority names the mug a cup; a view names it right
    assert stats["ceiling_miou"] == 100.0
    assert stats["majority_miou"] == 66.67  # floor and table right, the mug (a cup) wrong
