"""Refining the cluster labelling with the Gaussians' own class evidence.

The scene: 12 Gaussians one unit apart on the x axis, cluster 0 = Gaussians 0-7 and cluster 1
= 8-11. The class evidence of Gaussians 0-5 says class 0, that of 6-11 class 1: Gaussians 6
and 7 are a piece of a class-1 object that clustering put in cluster 0.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from numpy.typing import NDArray

from dcseg.assign.config import AssignConfig
from dcseg.assign.refinement import (
    drop_inconsistent,
    regroup_rejected,
    supported_votes,
    trusted_settings,
)
from dcseg.assign.stage import Assignment
from dcseg.cluster.features import Clustering

N = 12
MEANS = np.stack([np.arange(N, dtype=np.float64), np.zeros(N), np.zeros(N)], axis=1)
CLUSTERS = np.array([0] * 8 + [1] * 4)
FEATURES = np.tile(np.array([1.0, 0.0], np.float32), (N, 1))
FEATURES[6:8] = [0.0, 2.0]  # the piece's features point elsewhere


def evidence(split: int = 6) -> NDArray[np.float64]:
    """Gaussians before ``split`` give class 0 all their evidence, the others class 1."""
    out = np.zeros((N, 2))
    out[:split, 0] = 1.8
    out[split:, 1] = 1.8
    return out


def clustering(labels: NDArray[np.int64] = CLUSTERS, k: int = 2) -> Clustering:
    return Clustering(labels.copy(), np.eye(k, 2, dtype=np.float32), np.ones(N, np.float32))


def assignment(labels: list[int], votes: list[list[float]]) -> Assignment:
    v = np.array(votes)
    scores = v[np.arange(len(labels)), labels] / v.sum(axis=1)
    return Assignment(np.array(labels), scores, v, np.full(len(labels), 2))


SUPPORT = AssignConfig(min_cluster_support=0.1, support_min_extent=0.5)


def test_a_vote_the_clusters_evidence_does_not_support_takes_the_supported_class() -> None:
    """Cluster 0 (all its evidence class 0 here) voted class 1: it takes class 0, scored by
    class 0's share of its IoU votes (1 of 4); cluster 1's vote stands."""
    voted = assignment([1, 1], [[1.0, 3.0], [0.0, 2.0]])
    out, replaced = supported_votes(evidence(split=8), clustering(), voted, MEANS, SUPPORT)
    assert replaced == 1
    assert out.labels.tolist() == [0, 1] and out.scores.tolist() == [0.25, 1.0]
    assert np.array_equal(out.votes, voted.votes) and np.array_equal(out.n_views, voted.n_views)
    assert voted.labels.tolist() == [1, 1]  # the input is not changed


@pytest.mark.parametrize(
    "cfg",
    [replace(SUPPORT, min_cluster_support=0.0), replace(SUPPORT, support_min_extent=7.0)],
    ids=["off", "small"],
)
def test_votes_stand_when_off_or_for_clusters_smaller_than_the_extent(cfg: AssignConfig) -> None:
    """Cluster 0 spans 7 units less its tails (6.3): below ``support_min_extent`` 7 it counts
    as a small object the maps may miss."""
    voted = assignment([1, 1], [[1.0, 3.0], [0.0, 2.0]])
    out, replaced = supported_votes(evidence(split=8), clustering(), voted, MEANS, cfg)
    assert replaced == 0 and out is voted


def test_small_clusters_weakly_matched_take_their_supported_class() -> None:
    """Cluster 0 is small (extent 7) but matched at a mean IoU of 0.8 / 2 views = 0.4;
    ``support_min_iou`` above that counts its vote as weak anyway, below it the vote stands.
    Cluster 1 (supported) keeps its vote whatever its IoU."""
    voted = assignment([1, 1], [[0.2, 0.6], [0.0, 0.2]])
    small = replace(SUPPORT, support_min_extent=7.0)
    out, replaced = supported_votes(
        evidence(split=8), clustering(), voted, MEANS, replace(small, support_min_iou=0.5)
    )
    assert replaced == 1 and out.labels.tolist() == [0, 1]
    kept, replaced = supported_votes(
        evidence(split=8), clustering(), voted, MEANS, replace(small, support_min_iou=0.3)
    )
    assert replaced == 0 and kept is voted


@pytest.mark.parametrize("value", [-0.1, 1.5, float("nan")])
def test_support_min_iou_out_of_range_is_refused(value: float) -> None:
    with pytest.raises(ValueError, match="support_min_iou"):
        AssignConfig(support_min_iou=value)


def test_trusted_settings_replace_the_usual_ones_when_the_masks_agree() -> None:
    cfg = AssignConfig(
        trust_agreement=0.9, trusted_share_ratio=0.8, trusted_evidence_weight=5.0,
        trusted_follow_ratio=0.7, regroup_min_gaussians=30,
    )  # fmt: skip
    trusted, ok = trusted_settings(cfg, 0.95)
    assert ok
    assert trusted == replace(
        cfg, min_share_ratio=0.8, evidence_weight=5.0, regroup_min_gaussians=0,
        follow_evidence_ratio=0.7,
    )  # fmt: skip
    for agreement in (0.5, float("nan")):
        kept, ok = trusted_settings(cfg, agreement)
        assert not ok and kept is cfg
    never, ok = trusted_settings(replace(cfg, trust_agreement=None), 1.0)
    assert not ok and never.min_share_ratio == cfg.min_share_ratio


def geometry(radius: float = 1.5, stuff: tuple[int, ...] = ()):
    return (FEATURES, MEANS, radius, stuff)


def test_gaussians_their_evidence_contradicts_leave_their_cluster() -> None:
    """Cluster 0 gives class 0 a share of 6/8; Gaussians 6-7 give it none and leave (below
    0.5 x 0.75). Regrouping off, they are noise and both clusters stay."""
    voted = assignment([0, 1], [[2.0, 0.0], [0.0, 2.0]])
    cfg = AssignConfig(min_share_ratio=0.5, regroup_min_gaussians=0)
    kept, out = drop_inconsistent(evidence(), clustering(), voted, geometry(), cfg)
    assert kept.labels.tolist() == [0] * 6 + [-1] * 2 + [1] * 4
    assert out.labels.tolist() == [0, 1] and np.array_equal(out.votes, voted.votes)
    same, _ = drop_inconsistent(
        evidence(), clustering(), voted, geometry(), replace(cfg, min_share_ratio=0.0)
    )
    assert same.labels.tolist() == CLUSTERS.tolist()


def test_empty_clusters_go_and_the_rest_are_numbered_again() -> None:
    """Cluster 1 has no Gaussian: it goes, cluster 2 becomes 1 and the assignment follows."""
    labels = np.where(CLUSTERS == 1, 2, CLUSTERS)
    voted = assignment([0, 0, 1], [[2.0, 0.0], [1.0, 0.0], [0.0, 2.0]])
    cfg = AssignConfig(min_share_ratio=0.5, regroup_min_gaussians=0)
    kept, out = drop_inconsistent(evidence(), clustering(labels, 3), voted, geometry(), cfg)
    assert kept.labels.tolist() == [0] * 6 + [-1] * 2 + [1] * 4
    assert kept.centers.tolist() == np.eye(3, 2)[[0, 2]].tolist()
    assert out.labels.tolist() == [0, 1] and out.votes.tolist() == [[2.0, 0.0], [0.0, 2.0]]


def test_a_touching_group_that_left_a_cluster_becomes_a_cluster_of_its_own() -> None:
    """With ``regroup_min_gaussians`` 2, Gaussians 6-7 (1 unit apart, within the radius) are
    cluster 2, class 1 by all of their evidence, without IoU votes; its centre is their mean
    feature at unit norm. With 3, a radius of 0, or class 1 a stuff class, they stay noise."""
    voted = assignment([0, 1], [[2.0, 0.0], [0.0, 2.0]])
    cfg = AssignConfig(min_share_ratio=0.5, regroup_min_gaussians=2)
    kept, out = drop_inconsistent(evidence(), clustering(), voted, geometry(), cfg)
    assert kept.labels.tolist() == [0] * 6 + [2] * 2 + [1] * 4
    assert kept.centers[2].tolist() == [0.0, 1.0]
    assert out.labels.tolist() == [0, 1, 1] and out.scores.tolist() == [1.0, 1.0, 1.0]
    assert out.votes[2].tolist() == [0.0, 0.0] and out.n_views.tolist() == [2, 2, 0]
    noise = [0] * 6 + [-1] * 2 + [1] * 4
    for change, geo in (
        (replace(cfg, regroup_min_gaussians=3), geometry()),
        (cfg, geometry(radius=0.0)),
        (cfg, geometry(stuff=(1,))),
    ):
        dropped, _ = drop_inconsistent(evidence(), clustering(), voted, geo, change)
        assert dropped.labels.tolist() == noise


def test_a_group_under_the_minimum_becomes_a_cluster_when_its_evidence_is_unanimous() -> None:
    """Gaussians 6-7 are fewer than ``regroup_min_gaussians`` (3): with all their evidence
    for class 1 (share 1.0 >= ``regroup_unanimous_share``) and at least
    ``regroup_unanimous_gaussians`` (2) of them they are cluster 2, class 1; with some class-0
    evidence too (share 0.86), or that minimum off (0) or above them (3), they stay noise."""
    voted = assignment([0, 1], [[2.0, 0.0], [0.0, 2.0]])
    cfg = AssignConfig(
        min_share_ratio=0.5, regroup_min_gaussians=3, regroup_unanimous_gaussians=2,
        regroup_unanimous_share=0.95,
    )  # fmt: skip
    kept, out = drop_inconsistent(evidence(), clustering(), voted, geometry(), cfg)
    assert kept.labels.tolist() == [0] * 6 + [2] * 2 + [1] * 4
    assert out.labels.tolist() == [0, 1, 1]
    mixed = evidence()
    mixed[6:8, 0] = 0.3
    noise = [0] * 6 + [-1] * 2 + [1] * 4
    for ev, change in (
        (mixed, cfg),
        (evidence(), replace(cfg, regroup_unanimous_gaussians=0)),
        (evidence(), replace(cfg, regroup_unanimous_gaussians=3)),
    ):
        dropped, _ = drop_inconsistent(ev, clustering(), voted, geometry(), change)
        assert dropped.labels.tolist() == noise


def test_regroup_rejected_appends_groups_after_the_clusters() -> None:
    left = np.where((CLUSTERS == 0) & (np.arange(N) >= 6), -1, CLUSTERS)
    origin = np.where(left == -1, 0, -1)
    voted = assignment([0, 1], [[2.0, 0.0], [0.0, 2.0]])
    cfg = AssignConfig(regroup_min_gaussians=2)
    grown, out = regroup_rejected(clustering(left), voted, origin, evidence(), geometry(), cfg)
    assert grown.labels.tolist() == [0] * 6 + [2] * 2 + [1] * 4
    assert grown.centers.dtype == np.float32 and grown.centers.shape == (3, 2)
    assert out.labels.tolist() == [0, 1, 1] and out.n_views.tolist() == [2, 2, 0]
    none = np.full(N, -1)
    same, kept = regroup_rejected(clustering(left), voted, none, evidence(), geometry(), cfg)
    assert same.labels.tolist() == left.tolist() and kept is voted


def test_docstring_examples() -> None:
    import doctest

    import dcseg.assign.refinement as module

    assert doctest.testmod(module, raise_on_error=True).attempted > 0
