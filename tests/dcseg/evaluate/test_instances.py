"""Instance metrics: one-to-one matching at IoU >= 0.5 on ground-truth points."""

from __future__ import annotations

import math

import numpy as np
import pytest

from dcseg.evaluate.instances import instance_metrics, pair_iou


def test_a_perfect_prediction_scores_one_with_any_ids() -> None:
    gt = np.repeat([0, 1, 2], 100)
    m = instance_metrics(gt, np.repeat([7, 3, 9], 100))
    assert (m["precision"], m["recall"], m["f1"], m["mcov"]) == (1.0, 1.0, 1.0, 1.0)
    assert m["matches"] == 3 and m["count_ratio"] == 1.0


def test_fragments_cost_precision_and_one_match_per_object() -> None:
    """Object 0 split into halves: one half matches (IoU 0.5), the other is a false positive;
    a prediction can never match two objects (one-to-one)."""
    gt = np.repeat([0, 1], 100)
    pred = np.concatenate([np.repeat([10, 11], 50), np.full(100, 12)])
    m = instance_metrics(gt, pred)
    assert m["matches"] == 2 and m["n_pred"] == 3
    assert m["precision"] == pytest.approx(2 / 3) and m["recall"] == 1.0
    assert m["f1"] == pytest.approx(0.8) and m["mcov"] == pytest.approx(0.75)
    merged = instance_metrics(gt, np.full(200, 4))  # one instance covering both objects
    assert merged["matches"] == 1 and merged["recall"] == 0.5 and merged["mcov"] == 0.5


def test_below_threshold_is_no_match_and_small_instances_are_left_out() -> None:
    gt = np.repeat([0], 100)
    pred = np.concatenate([np.full(49, 1), np.full(51, 2)])  # IoU 0.51 for 2; 1 too small
    m = instance_metrics(gt, pred, n_written=30)
    assert m["n_pred"] == 1 and m["matches"] == 1 and m["n_written"] == 30
    assert m["count_ratio"] == 30.0
    strict = instance_metrics(gt, pred, iou_threshold=0.6)
    assert strict["matches"] == 0 and strict["f1"] == 0.0
    assert strict["mcov"] == pytest.approx(0.51)


def test_hungarian_beats_greedy() -> None:
    """Greedy on the largest IoU pairs A with object 0 (0.43) and leaves object 1 unmatched;
    the one-to-one assignment pairs B with 0 and A with 1, two matches at IoU >= 0.25."""
    gt = np.repeat([0, 1], [100, 100])
    pred = np.concatenate([np.full(60, 5), np.full(40, 6), np.full(40, 5), np.full(60, -1)])
    iou = pair_iou(gt, pred, np.array([0, 1]), np.array([5, 6]))
    assert np.allclose(iou, [[60 / 140, 0.4], [0.25, 0.0]])
    m = instance_metrics(gt, pred, min_points=10, iou_threshold=0.25)
    assert m["matches"] == 2 and m["mcov"] == pytest.approx((60 / 140 + 0.25) / 2)


def test_unlabelled_points_and_bad_input() -> None:
    gt = np.concatenate([np.full(100, 0), np.full(100, -1)])
    pred = np.full(200, 3)  # covers the unscored points too: they do not count
    assert instance_metrics(gt, pred)["matches"] == 1
    empty = instance_metrics(np.full(10, -1), np.full(10, -1))
    assert math.isnan(empty["f1"]) and empty["n_gt"] == 0
    with pytest.raises(ValueError, match="gt_instances has 3 points but pred_instances has 2"):
        instance_metrics(np.zeros(3), np.zeros(2))
    with pytest.raises(ValueError, match="iou_threshold"):
        instance_metrics(np.zeros(3), np.zeros(3), iou_threshold=0.0)
