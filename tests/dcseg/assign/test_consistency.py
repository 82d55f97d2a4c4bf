"""Gaussians contradicted by their own class evidence: the relative share test."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from dcseg.assign.config import AssignConfig
from dcseg.assign.consistency import (
    follow_evidence,
    inconsistent,
    mask_agreement,
    pooled_evidence,
    rejected_groups,
    spread,
    unsupported,
)


def test_far_below_the_cluster_share_is_inconsistent() -> None:
    labels = np.array([0, 0, 0, 0])
    classes = np.array([2, 2, 2, 2])
    agree = np.array([0.9, 0.9, 0.3, 0.2])
    total = np.ones(4)
    # Cluster share = 2.3 / 4 = 0.575; half of it is 0.2875.
    assert inconsistent(labels, classes, agree, total, 0.5).tolist() == [False, False, False, True]


def test_rare_class_cluster_keeps_its_uniformly_weak_gaussians() -> None:
    # A class the maps miss in most views: every Gaussian has a small share, none is an outlier.
    labels = np.array([0, 0, 0, 1, 1])
    classes = np.array([5, 5, 5, 1, 1])
    agree = np.array([0.1, 0.12, 0.09, 0.9, 0.05])
    total = np.ones(5)
    assert inconsistent(labels, classes, agree, total, 0.5).tolist() == [
        False,
        False,
        False,
        False,
        True,
    ]


def test_noise_unlabelled_and_unseen_gaussians_stay() -> None:
    labels = np.array([-1, 0, 1, 1])
    classes = np.array([-1, -1, 3, 3])
    agree = np.array([0.0, 0.0, 0.0, 4.0])
    total = np.array([5.0, 5.0, 0.0, 4.0])
    # Noise, an unlabelled cluster and a Gaussian without evidence are never inconsistent.
    assert not inconsistent(labels, classes, agree, total, 1.0).any()


def test_ratio_zero_keeps_everything() -> None:
    labels = np.array([0, 0])
    assert not inconsistent(labels, labels, np.array([0.0, 1.0]), np.ones(2), 0.0).any()


def test_exception_bad_ratio_and_shapes() -> None:
    labels = np.zeros(2, dtype=np.int64)
    with pytest.raises(ValueError, match="min_ratio must be in"):
        inconsistent(labels, labels, np.zeros(2), np.ones(2), 1.5)
    with pytest.raises(ValueError, match=r"cluster_labels \(2,\), classes \(2,\), agree \(3,\)"):
        inconsistent(labels, labels, np.zeros(3), np.ones(2), 0.1)
    with pytest.raises(ValueError, match="min_share_ratio must be in"):
        AssignConfig(min_share_ratio=-0.1)


def test_mask_agreement_weighs_evidence_of_labelled_gaussians_only() -> None:
    ev = np.array([[3.0, 1.0], [0.0, 2.0], [5.0, 5.0], [0.0, 0.0]])
    assert mask_agreement(np.array([0, 1, -1, 0]), ev) == pytest.approx(5 / 6)
    assert mask_agreement(np.array([1, 0, -1, -1]), ev) == pytest.approx(1 / 6)
    assert np.isnan(mask_agreement(np.array([-1, -1, -1, 0]), ev))
    with pytest.raises(ValueError, match="N rows"):
        mask_agreement(np.array([0, 1]), ev)


@pytest.mark.parametrize(
    "field, value",
    [("trust_agreement", 1.5), ("trust_agreement", -0.1), ("trusted_share_ratio", 2.0),
     ("trusted_evidence_weight", -1.0), ("min_cluster_support", 1.5),
     ("min_cluster_support", -0.1), ("support_min_extent", -1.0),
     ("support_min_extent", float("nan")), ("regroup_min_gaussians", -1),
     ("regroup_unanimous_gaussians", -1), ("regroup_unanimous_share", 1.5),
     ("follow_evidence_ratio", 1.5), ("trusted_follow_ratio", -0.1)],
)  # fmt: skip
def test_trust_support_and_regroup_settings_are_checked(field: str, value: float) -> None:
    changes: dict[str, Any] = {field: value}
    with pytest.raises(ValueError, match=field):
        AssignConfig(**changes)


def test_floor_cluster_voted_as_an_object_is_unsupported() -> None:
    """Cluster 0 (floor, class 0) was voted class 2 (a domino beside it): its own evidence
    gives class 2 1 % of class 0's. Cluster 1, voted the look-alike class 1, has 0.3 of its
    best class's evidence: a confusion the masks repeat, not a stray vote; it stays."""
    labels = np.array([0, 0, 0, 1, 1, -1])
    assigned = np.array([2, 1])
    evidence = np.array(
        [[5.0, 0.0, 0.1], [4.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.6, 2.0], [0.0, 0.3, 1.0],
         [0.0, 0.0, 9.0]]
    )  # fmt: skip
    pooled = pooled_evidence(labels, evidence, 2)
    assert unsupported(pooled, assigned, 0.1).tolist() == [True, False]
    assert unsupported(pooled, assigned, 0.5).tolist() == [True, True]
    assert not unsupported(pooled, assigned, 0.0).any()


def test_unlabelled_and_unseen_clusters_are_never_unsupported() -> None:
    labels = np.array([0, 1, 2])
    evidence = np.array([[1.0, 0.0], [0.0, 0.0], [0.0, 3.0]])
    # cluster 0 unlabelled; cluster 1 seen by no class map; cluster 2 has no Gaussian at all
    pooled = pooled_evidence(labels[:2], evidence[:2], 3)
    assert not unsupported(pooled, np.array([-1, 0, 1]), 1.0).any()


def test_exception_unsupported_shapes_and_support() -> None:
    with pytest.raises(ValueError, match="min_support"):
        unsupported(np.ones((1, 2)), np.zeros(1, int), 1.5)
    with pytest.raises(ValueError, match=r"\[K, C\] and \[K\]"):
        unsupported(np.ones((2, 2)), np.zeros(1, int), 0.1)


def test_rejected_groups_keep_the_class_their_evidence_pools_to() -> None:
    """Gaussians 0-3 left cluster 0 and touch (0.1 apart): one group, class 1 by its pooled
    evidence, which Gaussian 3 supports less. Gaussians 4-5 left cluster 0 too but sit
    5 m away: a group of 2, below ``min_size``. Gaussians 6-7 touch 0-3 but left cluster 1:
    another group, also too small. Gaussian 8 left nothing."""
    means = np.zeros((9, 3))
    means[:4, 0] = [0.0, 0.1, 0.2, 0.3]
    means[4:6, 0] = [5.0, 5.1]
    means[6:8, 0] = [0.35, 0.4]
    origin = np.array([0, 0, 0, 0, 0, 0, 1, 1, -1])
    evidence = np.array([[0.0, 1.0]] * 3 + [[0.4, 0.6]] + [[1.0, 0.0]] * 5)
    groups = rejected_groups(means, origin, evidence, radius=0.15, min_size=3)
    assert groups.ids.tolist() == [0, 0, 0, 0, -1, -1, -1, -1, -1]
    assert groups.classes.tolist() == [1]
    assert groups.shares == pytest.approx([3.6 / 4])
    smaller = rejected_groups(means, origin, evidence, radius=0.15, min_size=2)
    assert smaller.ids.tolist() == [0, 0, 0, 0, 1, 1, 2, 2, -1]
    assert smaller.classes.tolist() == [1, 0, 0]


def test_rejected_groups_split_touching_pieces_their_own_evidence_names_apart() -> None:
    """A tray (Gaussians 0-5, evidence class 1) and the mug on it (6-9, class 2) both left
    the table's cluster 0 and touch: two groups, not one group of the tray's class. Gaussian
    10 touches the mug but its own evidence says tray: alone, it is in no group."""
    means = np.zeros((11, 3))
    means[:6, 0] = 0.1 * np.arange(6)
    means[6:10, 0] = 0.55 + 0.1 * np.arange(4)
    means[10, 0] = 0.9
    evidence = np.zeros((11, 3))
    evidence[:6, 1] = 1.0
    evidence[6:10, 2] = 1.0
    evidence[10] = [0.0, 0.6, 0.4]
    groups = rejected_groups(means, np.zeros(11, int), evidence, radius=0.15, min_size=3)
    assert groups.ids.tolist() == [0] * 6 + [1] * 4 + [-1]
    assert groups.classes.tolist() == [1, 2]


def test_rejected_groups_without_evidence_or_members_stay_unlabelled() -> None:
    means = np.zeros((3, 3))
    means[:, 0] = [0.0, 0.1, 0.2]
    unseen = rejected_groups(means, np.zeros(3, int), np.zeros((3, 2)), 0.15, min_size=1)
    assert unseen.ids.tolist() == [-1, -1, -1] and len(unseen.classes) == 0
    none_left = rejected_groups(means, np.full(3, -1), np.ones((3, 2)), 0.15, min_size=1)
    assert none_left.ids.tolist() == [-1, -1, -1] and len(none_left.classes) == 0


def test_exception_rejected_groups_shapes_and_settings() -> None:
    with pytest.raises(ValueError, match=r"\[N, 3\], \[N\] and \[N, C\]"):
        rejected_groups(np.zeros((3, 2)), np.zeros(3, int), np.ones((3, 2)), 0.1, 1)
    with pytest.raises(ValueError, match="radius must be > 0 and min_size >= 1"):
        rejected_groups(np.zeros((3, 3)), np.zeros(3, int), np.ones((3, 2)), 0.1, 0)


def test_spread_is_the_largest_side_without_the_tails() -> None:
    rng = np.random.default_rng(0)
    patch = rng.uniform([0.0, 0.0, 0.0], [2.0, 1.0, 0.01], size=(2000, 3))
    assert spread(patch) == pytest.approx(1.8, abs=0.05)  # 5th to 95th percentile of 2 m
    stray = np.vstack([patch[:200] * 0.01, [[30.0, 0.0, 0.0]]])  # a 2 cm object, one floater
    assert spread(stray) < 0.03
    with pytest.raises(ValueError, match=r"\[M, 3\] with M >= 1"):
        spread(np.zeros((0, 3)))


def test_follow_evidence_moves_only_gaussians_their_evidence_contradicts() -> None:
    ev = np.array([[1.0, 3.0], [2.0, 2.1], [0.0, 0.0], [0.0, 1.0], [5.0, 0.0]])
    labels = np.array([0, 0, 0, -1, 0])
    assert follow_evidence(labels, ev, 0.9).tolist() == [1, 0, 0, 1, 0]
    assert follow_evidence(labels, ev, 1.0).tolist() == [1, 1, 0, 1, 0]  # the 3D vote
    assert follow_evidence(labels, ev, 0.0).tolist() == labels.tolist()
    with pytest.raises(ValueError, match="min_ratio"):
        follow_evidence(labels, ev, 1.5)
    with pytest.raises(ValueError, match="N rows"):
        follow_evidence(labels[:3], ev, 0.5)
