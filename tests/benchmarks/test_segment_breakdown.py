"""segment_breakdown: per-object decisions, per-class IoU and false-positive sources."""

from __future__ import annotations

import numpy as np

from benchmarks.segment_breakdown import class_rows, majority, object_rows, sources
from dcseg.types import GroundTruth

NAMES = ("table", "mug")


def _scene() -> tuple[GroundTruth, dict[str, np.ndarray]]:
    """Object 1 (table, 6 points), object 2 (mug, 4 points); "ring" labels two table points
    mug, "wrong" names the mug table."""
    labels = np.array([0] * 6 + [1] * 4, dtype=np.int64)
    instances = np.array([1] * 6 + [2] * 4, dtype=np.int64)
    gt = GroundTruth(np.zeros((10, 3)), labels, instances)
    ring = labels.copy()
    ring[:2] = 1
    wrong = np.zeros(10, dtype=np.int64)
    return gt, {"ring": ring, "wrong": wrong}


def test_majority_ignores_unlabelled_but_counts_it_in_the_share() -> None:
    assert majority(np.array([2, 2, -1, 3])) == (2, 0.5)
    assert majority(np.array([-1, -1])) == (-1, 0.0)


def test_object_rows_name_each_methods_majority_class() -> None:
    gt, preds = _scene()
    rows = object_rows(gt, preds, NAMES)
    assert len(rows) == 2
    assert rows[1].split("|")[1].split() == ["mug", "1.00"]
    assert rows[1].split("|")[2].split() == ["table", "1.00"]


def test_class_rows_give_iou_per_class_and_the_mean() -> None:
    gt, preds = _scene()
    rows = class_rows(gt, preds, NAMES)
    # ring: table 4/6, mug 4/6; wrong: table 6/10, mug 0
    assert rows[0].split() == ["table", "66.7", "60.0"]
    assert rows[1].split() == ["mug", "66.7", "0.0"]
    assert rows[-1].split() == ["mIoU", "66.7", "30.0"]


def test_sources_say_which_objects_a_class_was_predicted_on() -> None:
    gt, preds = _scene()
    assert sources(gt, preds, 1) == ["   ring: 1: 2, 2: 4", "  wrong: "]
