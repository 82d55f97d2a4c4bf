"""Consistent class confusions undone by the minority of views that name objects right."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.typing import NDArray

from dcseg.assign import AssignConfig, assign_labels
from dcseg.assign.config import Companions
from dcseg.assign.confusion import (
    companions,
    dependent_classes,
    named_alone,
    unanimous_share,
    undo_confusions,
    view_counts,
)


def lookalike_views(
    n_views: int, wrong_every: int
) -> tuple[list[NDArray[np.int64]], list[NDArray[np.int64]]]:
    """Three objects side by side (clusters 0, 1, 2): a ball (class 0) named right in every
    view, a second ball named globe (class 2) except in every ``wrong_every``-th view, and a
    bowl (class 1) named right everywhere."""
    ids = np.repeat(np.arange(3), 10)[None, :].repeat(4, axis=0)
    cluster_maps, class_maps = [], []
    for v in range(n_views):
        classes = np.repeat(np.array([0, 2 if v % wrong_every else 0, 1]), 10)
        cluster_maps.append(ids)
        class_maps.append(classes[None, :].repeat(4, axis=0))
    return cluster_maps, class_maps


def test_view_counts_counts_views_not_iou() -> None:
    counts = view_counts([[(0, 1, 0.3), (1, 0, 0.9)], [(0, 1, 0.8)]], 2, 2)
    assert counts.tolist() == [[0, 2], [1, 0]]


def test_companion_needs_share_views_and_comparable_iou() -> None:
    counts = np.array([[16, 4], [16, 4], [23, 1], [10, 1]])
    votes = np.array([[12.0, 3.0], [12.0, 0.4], [15.0, 0.7], [7.0, 0.7]])
    found = companions(np.array([0, 0, 0, 0]), counts, votes, 0.1, 2, 0.5)
    # 1: the other class's masks cover it poorly (bleeding); 2: one view; 3: one view of 11
    assert found.tolist() == [1, -1, -1, -1]


def test_a_class_seen_alone_is_real() -> None:
    counts = np.array([[20, 5], [24, 0]])
    labels = np.array([0, 0])
    found = companions(labels, counts, counts * 0.7, 0.1, 2, 0.5)
    assert dependent_classes(labels, found, counts, 20).tolist() == [False, False]
    assert undo_confusions(labels, counts, counts * 0.7, 0.1, 2, 0.5).tolist() == [0, 0]


def test_untested_clusters_do_not_make_a_class_real() -> None:
    """A fragment matched in too few views to show a companion neither blocks nor flips."""
    counts = np.array([[0, 5, 19], [0, 0, 3]])
    out = undo_confusions(np.array([2, 2]), counts, counts * 0.7, 0.2, 2, 0.5)
    assert out.tolist() == [1, 2]


def test_lookalike_in_most_views_is_undone_by_the_vote() -> None:
    cluster_maps, class_maps = lookalike_views(24, wrong_every=5)
    off = AssignConfig(min_area=0, confusion_min_share=0.0)
    plain = assign_labels(cluster_maps, class_maps, 3, 3, off)
    assert plain.labels.tolist() == [0, 2, 1]  # the majority elects the look-alike
    cfg = AssignConfig(min_area=0, confusion_min_share=0.1)
    fixed = assign_labels(cluster_maps, class_maps, 3, 3, cfg)
    assert fixed.labels.tolist() == [0, 0, 1]
    # the companion's share of the IoU votes: in its 5 views it shares class 0's mask
    assert fixed.scores[1] == pytest.approx(5 * 0.5 / (5 * 0.5 + 19))
    assert fixed.votes.tolist() == plain.votes.tolist()


def test_error_in_every_view_stays() -> None:
    cluster_maps, class_maps = lookalike_views(24, wrong_every=25)  # never named right
    cfg = AssignConfig(min_area=0, confusion_min_share=0.1)
    assert assign_labels(cluster_maps, class_maps, 3, 3, cfg).labels.tolist() == [0, 2, 1]


def test_no_vocabulary_changes_nothing() -> None:
    counts = np.zeros((3, 0), dtype=np.int64)
    labels = np.full(3, -1)
    assert undo_confusions(labels, counts, counts * 1.0, 0.15, 2, 0.5).tolist() == [-1, -1, -1]


def test_unanimous_share() -> None:
    counts = np.array([[5, 0], [4, 1], [0, 0]])
    assert unanimous_share(counts, np.array([0, 0, -1])) == 0.5
    assert np.isnan(unanimous_share(counts, np.array([-1, -1, -1])))


@pytest.mark.parametrize(
    "field",
    [
        {"confusion_min_share": -0.1},
        {"confusion_min_share": 1.5},
        {"confusion_min_views": 0},
        {"confusion_min_iou_ratio": -1.0},
        {"confusion_companion": "some"},
    ],
)
def test_config_rejects(field: dict[str, object]) -> None:
    with pytest.raises(ValueError, match=next(iter(field))):
        AssignConfig(**field)  # type: ignore[arg-type]


def test_companion_alone_keeps_a_minority_name_that_is_itself_a_confusion() -> None:
    """Per-view noise: a ball named bowl in a third of its views, and no object named bowl
    alone. Ungated, ball behaves like a confusion of bowl; gated, bowl does as much, and the
    vote stands."""
    counts = np.array([[16, 8, 0], [0, 0, 24]])  # classes: ball, bowl, table
    labels = np.array([0, 2])
    votes = counts * 0.6
    assert undo_confusions(labels, counts, votes, 0.15, 2, 0.5).tolist() == [1, 2]
    gated = undo_confusions(labels, counts, votes, 0.15, 2, 0.5, companion_alone=True)
    assert gated.tolist() == [0, 2]


def test_companion_alone_takes_a_companion_named_alone_elsewhere() -> None:
    """A ball named globe in most views (class 2), another ball named ball in every view."""
    counts = np.array([[4, 0, 19], [24, 0, 0]])
    labels = np.array([2, 0])
    votes = counts * 0.6
    gated = undo_confusions(labels, counts, votes, 0.15, 2, 0.5, companion_alone=True)
    assert gated.tolist() == [0, 0]


def test_mutual_companions_stay() -> None:
    """Ducks named teddy and teddies named duck in a third of their views: neither is named
    alone, so neither gives way when gated."""
    counts = np.array([[16, 8], [7, 17]])
    labels = np.array([0, 1])
    votes = counts * 0.6
    assert undo_confusions(labels, counts, votes, 0.15, 2, 0.5).tolist() == [1, 0]
    gated = undo_confusions(labels, counts, votes, 0.15, 2, 0.5, companion_alone=True)
    assert gated.tolist() == [0, 1]


def test_named_alone_counts_tested_clusters_only() -> None:
    counts = np.array([[3, 0], [20, 5]])
    assert named_alone(np.array([0, 0]), np.array([-1, 1]), counts, 10).tolist() == [False, False]


def test_config_companion_alone_reaches_the_vote() -> None:
    """Through the stage: the look-alike's companion (class 0) is named alone for the first
    ball, so the gated step still relabels the second ball."""
    cluster_maps, class_maps = lookalike_views(24, wrong_every=5)
    cfg = AssignConfig(min_area=0, confusion_min_share=0.1, confusion_companion="alone")
    assert assign_labels(cluster_maps, class_maps, 3, 3, cfg).labels.tolist() == [0, 0, 1]


def test_config_companion_alone_leaves_a_companion_nobody_is_named() -> None:
    """Only the second ball is in the scene: class 0 is named for no other object."""
    cluster_maps, class_maps = lookalike_views(24, wrong_every=5)
    cluster_maps = [np.where(ids == 0, -1, ids) for ids in cluster_maps]
    cases: tuple[tuple[Companions, list[int]], ...] = (("any", [-1, 0, 1]), ("alone", [-1, 2, 1]))
    for cfg_companion, expected in cases:
        cfg = AssignConfig(min_area=0, confusion_min_share=0.1, confusion_companion=cfg_companion)
        assert assign_labels(cluster_maps, class_maps, 3, 3, cfg).labels.tolist() == expected
