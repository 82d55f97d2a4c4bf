"""label_maps_iou: a run's label maps against per-frame ground-truth class images."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from benchmarks.label_maps_iou import _pairs, counts, score, summary


def test_counts_iou_per_class_and_background_given_an_object() -> None:
    truth = np.array([[0, 0, 5, 5, 7, 7]])
    predicted = np.array([[-1, 5, 5, -1, 7, 7]])
    table = counts(predicted, truth, [5, 7])
    assert table.tolist() == [[1, 3], [2, 2], [2, 1]]
    found = summary(table, [5, 7])
    assert found["iou"] == {"5": pytest.approx(33.3), "7": 100.0}
    assert found["mean_iou"] == pytest.approx(66.7) and found["background_labelled"] == 50.0


def test_label_maps_are_index_plus_one_and_truth_files_may_add_a_part_name(tmp_path: Path) -> None:
    """``labels/f0.png`` holds vocabulary index + 1 (0 = none) at half the truth's size;
    ``f0.segm.png`` is frame f0's truth; a truth file of no frame is left out."""
    run, truth = tmp_path / "run", tmp_path / "truth"
    (run / "labels").mkdir(parents=True)
    truth.mkdir()
    cv2.imwrite(str(run / "labels" / "f0.png"), np.array([[0, 6], [6, 0]], np.uint16))
    big = np.zeros((4, 4), np.uint8)
    big[:2, 2:] = big[2:, :2] = 5
    cv2.imwrite(str(truth / "f0.segm.png"), big)
    cv2.imwrite(str(truth / "other.png"), big)
    pairs = _pairs(run, truth)
    assert list(pairs) == ["f0"]
    found = summary(score(pairs.values(), [5]), [5])
    assert found["iou"] == {"5": 100.0} and found["background_labelled"] == 0.0
