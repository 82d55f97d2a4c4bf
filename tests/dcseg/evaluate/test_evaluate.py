"""Evaluation stage: confusion and metrics by hand, point transfer, projection vote."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.typing import NDArray

import dcseg.evaluate
from dcseg.evaluate import (
    REPLICA_CLASS_NAMES,
    REPLICA_CLASSES,
    REPLICA_SPLIT,
    EvaluateConfig,
    confusion,
    evaluate_scenes,
    metrics_from_confusion,
    naive_fusion,
    replica_labels_from_raw,
    transfer_nearest,
    transfer_opaque,
    vote_projection,
)

NAMES = ["a", "b", "c", "d"]
GT = np.array([0, 0, 0, 0, 1, 1, 2, 2, -1])
PRED = np.array([0, 0, 1, -1, 1, -1, 1, 3, 2])


def test_confusion_skips_ignored_gt_and_has_no_prediction_column() -> None:
    conf = confusion(GT, PRED, 4)
    expected = np.array(
        [
            [2, 1, 0, 0, 1],
            [0, 1, 0, 0, 1],
            [0, 1, 0, 1, 0],
            [0, 0, 0, 0, 0],
        ]
    )
    np.testing.assert_array_equal(conf, expected)
    assert conf.sum() == 8  # the ignored point is not counted


def test_metrics_by_hand() -> None:
    m = metrics_from_confusion(confusion(GT, PRED, 4), NAMES)
    # a: TP 2, FN 2 (one wrong, one no prediction), FP 0 -> IoU 2/4, Acc 2/4
    # b: TP 1, FN 1, FP 2 (from a and c) -> IoU 1/4, Acc 1/2
    # c: TP 0, FN 2 -> 0, 0;  d: absent from GT -> NaN, excluded from the means
    assert m["iou"]["a"] == pytest.approx(0.5) and m["acc"]["a"] == pytest.approx(0.5)
    assert m["iou"]["b"] == pytest.approx(0.25) and m["acc"]["b"] == pytest.approx(0.5)
    assert m["iou"]["c"] == 0.0 and m["acc"]["c"] == 0.0
    assert math.isnan(m["iou"]["d"]) and math.isnan(m["acc"]["d"])
    assert m["miou"] == pytest.approx(0.75 / 3)
    assert m["macc"] == pytest.approx(1.0 / 3)
    assert m["present"] == ["a", "b", "c"]
    assert m["n_points"] == 8 and m["no_prediction"] == 2
    assert "splits" not in m


def test_metrics_splits() -> None:
    split = {"x": [0, 1], "y": [2, 3], "z": [3]}
    m = metrics_from_confusion(confusion(GT, PRED, 4), NAMES, split)
    assert m["splits"]["x"] == {"miou": pytest.approx(0.375), "macc": 0.5, "n_present": 2}
    assert m["splits"]["y"] == {"miou": 0.0, "macc": 0.0, "n_present": 1}
    assert math.isnan(m["splits"]["z"]["miou"]) and m["splits"]["z"]["n_present"] == 0


def test_metrics_empty_and_exceptions() -> None:
    m = metrics_from_confusion(np.zeros((2, 3), np.int64), ["a", "b"])
    assert math.isnan(m["miou"]) and m["present"] == []
    with pytest.raises(ValueError, match="class names"):
        metrics_from_confusion(np.zeros((2, 3)), ["a"])
    with pytest.raises(ValueError, match=r"\[C, C \+ 1\]"):
        metrics_from_confusion(np.zeros((2, 2)), ["a", "b"])
    with pytest.raises(ValueError, match="pred values"):
        confusion(np.array([0]), np.array([4]), 4)
    with pytest.raises(ValueError, match="points"):
        confusion(np.array([0, 1]), np.array([0]), 4)


def test_evaluate_scenes_pools_confusions() -> None:
    cfg = EvaluateConfig()
    pooled = evaluate_scenes([GT[:4], GT[4:]], [PRED[:4], PRED[4:]], NAMES, cfg)
    whole = metrics_from_confusion(confusion(GT, PRED, 4), NAMES)
    assert pooled["miou"] == pytest.approx(whole["miou"])
    assert pooled["confusion"] == confusion(GT, PRED, 4).tolist()
    with pytest.raises(ValueError, match="unknown split"):
        evaluate_scenes([GT], [PRED], NAMES, EvaluateConfig(split="scannet"))
    with pytest.raises(ValueError, match="GT scenes"):
        evaluate_scenes([GT], [], NAMES, cfg)


def test_evaluate_scenes_with_replica_split() -> None:
    gt = np.array([0, 20, 40, 40])
    pred = np.array([0, 20, 40, -1])
    m = evaluate_scenes([gt], [pred], REPLICA_CLASS_NAMES, EvaluateConfig(split="replica"))
    assert m["splits"]["head"] == {"miou": 1.0, "macc": 1.0, "n_present": 1}
    assert m["splits"]["tail"] == {"miou": 0.5, "macc": 0.5, "n_present": 1}
    assert m["present"] == ["wall", "vent", "clock"]


def test_transfer_nearest_with_max_distance() -> None:
    xyz = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0]])
    labels = np.array([1, -1, 2])
    points = np.array([[0.05, 0, 0], [0.95, 0, 0], [2.3, 0, 0], [0, 0.2, 0], [1.8, 0, 0]])
    out = transfer_nearest(xyz, labels, points, max_distance=0.2)
    # exactly 0.2 away still counts; nearest-but-unlabelled gives no prediction
    np.testing.assert_array_equal(out, [1, -1, -1, 1, 2])
    assert transfer_nearest(np.zeros((0, 3)), np.zeros(0), points, 1.0).tolist() == [-1] * 5
    with pytest.raises(ValueError, match="gaussian_labels"):
        transfer_nearest(xyz, labels[:2], points, 0.2)


def test_transfer_opaque_follows_the_evaluation_protocol() -> None:
    """evaluation.md: the nearest Gaussian with opacity above 0.05, if within 5 cm. A nearer
    transparent Gaussian must not win, and 6 cm is too far."""
    xyz = np.array([[0.0, 0, 0], [0.03, 0, 0]])
    opacity = np.array([0.01, 0.9])
    labels = np.array([0, 1])
    points = np.array([[0.0, 0, 0], [0.09, 0, 0]])
    out = transfer_opaque(xyz, opacity, labels, points, EvaluateConfig())
    np.testing.assert_array_equal(out, [1, -1])
    loose = EvaluateConfig(min_opacity=0.0, max_distance=0.1)
    np.testing.assert_array_equal(transfer_opaque(xyz, opacity, labels, points, loose), [0, 1])
    with pytest.raises(ValueError, match="min_opacity"):
        EvaluateConfig(min_opacity=1.0)


K = np.array([[10.0, 0, 4.5], [0, 10.0, 4.5], [0, 0, 1]])


def wall_view(depth: float = 2.0) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    labels = np.zeros((10, 10), dtype=np.int64)
    labels[:, 5:] = 1
    return labels, np.full((10, 10), depth)


def test_vote_projection_depth_test_rejects_occluded_points() -> None:
    labels, depth = wall_view()
    labels[9, :] = -1  # no label in the bottom row
    depth[0, :] = 0.0  # invalid depth in the top row
    points = np.array(
        [
            [-0.5, 0.0, 2.0],  # on the wall, left half -> 0
            [0.5, 0.0, 2.05],  # on the wall (within 0.1 m), right half -> 1
            [-0.5, 0.0, 4.0],  # behind the wall: fails the depth test
            [0.0, 0.0, -1.0],  # behind the camera
            [10.0, 0.0, 1.0],  # outside the image
            [0.0, -0.9, 2.0],  # lands in the top row: invalid depth
            [0.0, 0.9, 2.0],  # lands in the bottom row: no label
        ]
    )
    out = vote_projection(points, [labels], [depth], [K], [np.eye(4)], n_classes=2)
    np.testing.assert_array_equal(out, [0, 1, -1, -1, -1, -1, -1])


def test_vote_projection_majority_and_ties() -> None:
    labels, depth = wall_view()
    all2 = np.full((10, 10), 2)
    point = np.array([[-0.5, 0.0, 2.0]])
    two = vote_projection(point, [labels, all2], [depth] * 2, [K] * 2, [np.eye(4)] * 2, 3)
    three = vote_projection(point, [labels, all2, all2], [depth] * 3, [K] * 3, [np.eye(4)] * 3, 3)
    assert two.tolist() == [0]  # tie 1:1 -> smallest class index
    assert three.tolist() == [2]


def test_vote_projection_uses_camera_to_world_pose() -> None:
    # camera at z=4 looking back along -z (rotation 180 deg about y)
    c2w = np.diag([-1.0, 1.0, -1.0, 1.0])
    c2w[2, 3] = 4.0
    labels = np.tile(np.arange(10), (10, 1))  # label = column index
    depth = np.full((10, 10), 3.0)
    point = np.array([[0.3, 0.0, 1.0]])  # camera coords (-0.3, 0, 3) -> u = 3.5 -> column 4
    assert vote_projection(point, [labels], [depth], [K], [c2w], 10).tolist() == [4]


def test_vote_projection_exceptions() -> None:
    labels, depth = wall_view()
    pts = np.zeros((1, 3))
    with pytest.raises(ValueError, match="one entry per view"):
        vote_projection(pts, [labels], [depth], [], [np.eye(4)], 2)
    with pytest.raises(ValueError, match="label image"):
        vote_projection(pts, [labels], [depth[:5]], [K], [np.eye(4)], 2)
    with pytest.raises(ValueError, match="n_classes"):
        vote_projection(pts, [labels], [depth], [K], [np.eye(4)], 1)


def test_naive_fusion_is_the_projection_vote() -> None:
    assert naive_fusion is vote_projection


def test_replica_table_and_split() -> None:
    assert len(REPLICA_CLASSES) == 51
    assert len(set(REPLICA_CLASS_NAMES)) == 51
    assert len({raw for _, raw in REPLICA_CLASSES}) == 51
    assert REPLICA_CLASSES[0] == ("wall", 93)
    assert REPLICA_CLASSES[16] == ("blanket", 11)
    assert REPLICA_CLASSES[33] == ("monitor", 52)
    assert REPLICA_CLASSES[50] == ("switch", 79)
    assert [len(v) for v in REPLICA_SPLIT.values()] == [17, 17, 17]
    assert sorted(i for v in REPLICA_SPLIT.values() for i in v) == list(range(51))
    assert REPLICA_SPLIT["common"][0] == 17 and REPLICA_SPLIT["tail"][0] == 34
    raw = np.array([93, 79, -1, -2, 256, 5, 1000])
    np.testing.assert_array_equal(replica_labels_from_raw(raw), [0, 50, -1, -1, -1, -1, -1])


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"protocol": "mesh"}, "protocol"),
        ({"depth_tol": 0.0}, "depth_tol"),
        ({"max_distance": -1.0}, "max_distance"),
    ],
)
def test_exception_config(kwargs, match) -> None:
    with pytest.raises(ValueError, match=match):
        EvaluateConfig(**kwargs)


def test_all_is_sorted_and_complete() -> None:
    assert dcseg.evaluate.__all__ == sorted(dcseg.evaluate.__all__)
    for name in dcseg.evaluate.__all__:
        assert hasattr(dcseg.evaluate, name)


def test_docstring_examples() -> None:
    import doctest

    import dcseg.evaluate.stage as module

    assert doctest.testmod(module, raise_on_error=True).attempted > 0


def test_package_imports_without_torch() -> None:
    import subprocess
    import sys

    code = "import sys, dcseg.evaluate, dcseg.evaluate.config; print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
