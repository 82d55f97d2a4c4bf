"""Assignment stage: IoU histogram, 2D cleaning, replicated matching, IoU-weighted votes."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.typing import NDArray

import dcseg.assign
from dcseg.assign import (
    AssignConfig,
    assign_labels,
    class_replicas,
    clean_cluster_map,
    component_counts,
    mask_iou,
    match_view,
    tally,
    view_matches,
    vote,
)


def brute_iou(
    ids: NDArray[np.int64], classes: NDArray[np.int64], k: int, c: int
) -> NDArray[np.float64]:
    out = np.zeros((k, c))
    for i in range(k):
        for j in range(c):
            a, b = ids == i, classes == j
            union = (a | b).sum()
            out[i, j] = (a & b).sum() / union if union else 0.0
    return out


def test_mask_iou_matches_brute_force() -> None:
    rng = np.random.default_rng(0)
    ids = rng.integers(-1, 6, (20, 30))
    classes = rng.integers(-1, 4, (20, 30))
    iou = mask_iou(ids, classes, n_clusters=7, n_classes=5)  # cluster 6, class 4 absent
    assert iou.shape == (7, 5)
    np.testing.assert_allclose(iou, brute_iou(ids, classes, 7, 5))
    assert np.all(iou[6] == 0) and np.all(iou[:, 4] == 0)


def test_mask_iou_exceptions() -> None:
    with pytest.raises(ValueError, match="differ"):
        mask_iou(np.zeros((2, 2), int), np.zeros((2, 3), int), 1, 1)
    with pytest.raises(ValueError, match="cluster_ids values"):
        mask_iou(np.full((2, 2), 3), np.zeros((2, 2), int), 2, 1)
    with pytest.raises(ValueError, match="integer map"):
        mask_iou(np.zeros((2, 2)), np.zeros((2, 2), int), 1, 1)


def test_clean_cluster_map_drops_small_pieces_8_connected() -> None:
    ids = np.full((6, 8), -1)
    ids[0:3, 0:3] = 0  # 9 px piece of cluster 0
    ids[5, 7] = 0  # 1 px stray piece of cluster 0
    ids[3, 3] = 1  # cluster 1: two pixels touching diagonally = one 8-connected piece
    ids[4, 4] = 1
    ids[5, 0] = 2  # cluster 2: a single pixel
    out = clean_cluster_map(ids, min_area=2)
    expected = ids.copy()
    expected[5, 7] = -1
    expected[5, 0] = -1
    np.testing.assert_array_equal(out, expected)
    np.testing.assert_array_equal(clean_cluster_map(ids, min_area=0), ids)
    np.testing.assert_array_equal(clean_cluster_map(ids, min_area=10), np.full((6, 8), -1))


def test_component_counts() -> None:
    classes = np.full((4, 9), -1)
    classes[:, 0:2] = 0
    classes[:, 4:6] = 0
    classes[0, 8] = 0  # a 1-px piece
    classes[3, 8] = 2
    np.testing.assert_array_equal(component_counts(classes, 4, min_area=1), [3, 0, 1, 0])
    np.testing.assert_array_equal(component_counts(classes, 4, min_area=2), [2, 0, 1, 0])
    # a present class whose pieces are all small still counts once
    np.testing.assert_array_equal(component_counts(classes, 4, min_area=100), [1, 0, 1, 0])


IOU = np.array([[0.9, 0.0], [0.8, 0.1], [0.7, 0.0], [0.6, 0.0]])


def test_assignment_lets_one_class_take_three_clusters() -> None:
    matches = match_view(IOU, AssignConfig(replicas=3))
    # most valid edges first: class 1 takes cluster 1 (IoU 0.1) so that cluster 3 also gets
    # class 0, although {0,1,2} -> class 0 would have a larger IoU sum with one edge fewer
    assert matches == [(0, 0, 0.9), (1, 1, 0.1), (2, 0, 0.7), (3, 0, 0.6)]


def test_matching_is_one_to_one() -> None:
    assert match_view(IOU, AssignConfig(matcher="matching")) == [(0, 0, 0.9), (1, 1, 0.1)]
    assert match_view(IOU, AssignConfig(replicas=1)) == [(0, 0, 0.9), (1, 1, 0.1)]


def test_iou_floor_drops_weak_edges() -> None:
    iou = np.array([[0.04, 0.0], [0.5, 0.049]])
    assert match_view(iou, AssignConfig()) == [(1, 0, 0.5)]
    assert match_view(iou, AssignConfig(min_iou=0.01)) == [(0, 0, 0.04), (1, 0, 0.5)]
    matching = AssignConfig(matcher="matching", min_iou=0.01)
    assert match_view(iou, matching) == [(0, 0, 0.04), (1, 1, 0.049)]
    assert match_view(np.zeros((3, 2)), AssignConfig()) == []
    assert match_view(np.zeros((0, 2)), AssignConfig()) == []


def test_replicas_from_components() -> None:
    cfg = AssignConfig(replicas="components")
    assert match_view(IOU, cfg, counts=[2, 0]) == [(0, 0, 0.9), (1, 0, 0.8)]
    with pytest.raises(ValueError, match="component counts"):
        match_view(IOU, cfg)
    with pytest.raises(ValueError, match="counts must be"):
        class_replicas(2, cfg, np.array([1, 2, 3]))
    np.testing.assert_array_equal(class_replicas(3, AssignConfig(replicas=2)), [2, 2, 2])


def test_vote_weights_by_iou_ties_go_to_lowest_class() -> None:
    views = [
        [(0, 2, 0.5), (1, 1, 0.3)],
        [(0, 1, 0.5), (1, 1, 0.2), (2, 0, 0.1)],
        [(2, 3, 0.05), (2, 3, 0.04)],
    ]
    labels, scores = vote(views, n_clusters=4, n_classes=4)
    np.testing.assert_array_equal(labels, [1, 1, 0, -1])  # cluster 0: tie 0.5/0.5 -> class 1
    np.testing.assert_allclose(scores, [0.5, 1.0, 0.1 / 0.19, 0.0])
    votes, n_views = tally(views, 4, 4)
    np.testing.assert_allclose(votes[1], [0, 0.5, 0, 0])
    np.testing.assert_array_equal(n_views, [2, 2, 3, 0])


def scene() -> tuple[NDArray[np.int64], NDArray[np.int32]]:
    """Class 0 in two separate blocks, class 1 between them; one cluster per block."""
    classes = np.zeros((4, 12), dtype=np.int32)
    classes[:, 4:8] = 1
    ids = np.repeat(np.arange(3), 4)[None, :].repeat(4, axis=0)
    return ids, classes


def test_assign_labels_assignment_vs_matching_vs_components() -> None:
    ids, classes = scene()
    result = assign_labels([ids], [classes], 3, 2, AssignConfig(min_area=0))
    np.testing.assert_array_equal(result.labels, [0, 1, 0])
    np.testing.assert_allclose(result.votes, [[0.5, 0.0], [0.0, 1.0], [0.5, 0.0]])
    np.testing.assert_array_equal(result.n_views, [1, 1, 1])
    matching = assign_labels([ids], [classes], 3, 2, AssignConfig(matcher="matching", min_area=0))
    assert matching.labels[1] == 1 and sorted(matching.labels[[0, 2]].tolist()) == [-1, 0]
    comps = assign_labels([ids], [classes], 3, 2, AssignConfig(replicas="components", min_area=0))
    np.testing.assert_array_equal(comps.labels, [0, 1, 0])


def test_assign_labels_over_views_with_cleaning() -> None:
    ids, classes = scene()
    flipped = np.where(classes == 1, 0, 1).astype(np.int32)  # view 2 disagrees on cluster 1
    stray = ids.copy()
    stray[0, 0] = 1  # a 1-px piece of cluster 1 inside cluster 0's block (removed by cleaning)
    cfg = AssignConfig(min_area=2)
    stray = clean_cluster_map(stray, cfg.min_area)
    pieces = view_matches(stray, classes, 3, 2, cfg)
    assert (1, 1, 1.0) in pieces
    result = assign_labels([ids, stray, ids], [classes, classes, flipped], 4, 2, cfg)
    np.testing.assert_array_equal(result.labels, [0, 1, 0, -1])
    np.testing.assert_array_equal(result.n_views, [3, 3, 3, 0])
    np.testing.assert_allclose(result.votes[1], [1.0, 2.0])
    # cluster 0 in the cleaned stray view: 15 of its 16 px remain -> IoU with class 0 = 15/32
    np.testing.assert_allclose(result.votes[0], [0.5 + 15 / 32, 0.5])
    np.testing.assert_allclose(result.votes[2], [1.0, 0.5])
    np.testing.assert_allclose(result.scores, [(0.5 + 15 / 32) / 1.46875, 2 / 3, 2 / 3, 0])
    with pytest.raises(ValueError):
        result.labels[0] = 1


def test_assign_labels_degenerate_inputs() -> None:
    none = assign_labels([], [], 3, 2, AssignConfig())
    np.testing.assert_array_equal(none.labels, [-1, -1, -1])
    empty = np.zeros((0, 0), dtype=np.int64)
    assert assign_labels([empty], [empty], 2, 2, AssignConfig()).labels.tolist() == [-1, -1]


def test_assign_labels_exceptions() -> None:
    ids, classes = scene()
    with pytest.raises(ValueError, match="cluster maps"):
        assign_labels([ids], [], 3, 2, AssignConfig())
    with pytest.raises(ValueError, match="differ"):
        assign_labels([ids], [classes[:, :5]], 3, 2, AssignConfig())


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"matcher": "greedy"}, "matcher"),
        ({"replicas": 0}, "replicas"),
        ({"replicas": "instances"}, "replicas"),
        ({"min_iou": 0.0}, "min_iou"),
        ({"min_area": -1}, "min_area"),
    ],
)
def test_exception_config(kwargs, match) -> None:
    with pytest.raises(ValueError, match=match):
        AssignConfig(**kwargs)


def test_all_is_sorted_and_complete() -> None:
    assert dcseg.assign.__all__ == sorted(dcseg.assign.__all__)
    for name in dcseg.assign.__all__:
        assert hasattr(dcseg.assign, name)


def test_docstring_examples() -> None:
    import doctest

    import dcseg.assign.stage as module

    assert doctest.testmod(module, raise_on_error=True).attempted > 0


def test_package_imports_without_torch() -> None:
    import subprocess
    import sys

    code = "import sys, dcseg.assign, dcseg.assign.config; print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
