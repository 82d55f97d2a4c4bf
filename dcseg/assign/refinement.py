"""Refine a cluster labelling with the Gaussians' own class evidence (after the IoU votes).

The votes decide a class per cluster from whole cluster masks. Each Gaussian also carries its
own class evidence (its blending weight over the pixels each class-aware map gives each class,
:class:`dcseg.segment.EvidenceSum`), which corrects the votes in three ways, in this order:

1. a vote its cluster's pooled evidence does not support gives way to the class that evidence
   supports most (:func:`supported_votes`);
2. when the masks agree with the labelled clusters well enough, the trusted settings replace
   the usual ones (:func:`trusted_settings`);
3. Gaussians that their own evidence contradicts leave their cluster; touching groups of them
   become clusters of their own, and empty clusters go (:func:`drop_inconsistent`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dcseg.assign.config import AssignConfig
from dcseg.assign.consistency import (
    inconsistent,
    pooled_evidence,
    rejected_groups,
    spread,
    unsupported,
)
from dcseg.assign.stage import Assignment
from dcseg.cluster.features import Clustering, as_numpy
from dcseg.cluster.outliers import compact_labels
from dcseg.segment import label_map

Geometry = tuple[Any, NDArray[np.float64], float, Sequence[int]]
"""A scene's clustering features (``[N, D]`` array or tensor), Gaussian centres, contact
radius and the ids of its stuff classes (``AssignConfig.stuff_classes``)."""


def supported_votes(
    evidence: NDArray[np.float64],
    clustering: Clustering,
    assignment: Assignment,
    means: NDArray[np.float64],
    cfg: AssignConfig,
) -> tuple[Assignment, int]:
    """``assignment`` with each vote that its cluster's own pooled evidence does not support
    (:func:`~dcseg.assign.consistency.unsupported`, ``cfg.min_cluster_support``)
    replaced by the class that evidence supports most, for clusters that span at least
    ``cfg.support_min_extent`` (:func:`~dcseg.assign.consistency.spread` of their
    ``means``) or whose matched views' mean IoU is below ``cfg.support_min_iou``; its score
    becomes that class's share of the cluster's summed IoU votes (often 0: the masks' vote
    never reached it). Also returns how many votes were replaced."""
    a = assignment
    pooled = pooled_evidence(clustering.labels, evidence, len(a.labels))
    weak = unsupported(pooled, a.labels, cfg.min_cluster_support)
    per_view = np.divide(a.votes.sum(axis=1), a.n_views, out=np.zeros(len(a.labels)),
                         where=a.n_views > 0)  # fmt: skip
    for k in np.flatnonzero(weak):
        small_weak = per_view[k] < cfg.support_min_iou
        weak[k] = small_weak or spread(means[clustering.labels == k]) >= cfg.support_min_extent
    if not weak.any():
        return a, 0
    labels = a.labels.copy()
    labels[weak] = pooled[weak].argmax(axis=1)
    scores = a.scores.copy()
    total = a.votes[weak].sum(axis=1)
    won = a.votes[weak, labels[weak]]
    scores[weak] = np.divide(won, total, out=np.zeros_like(won), where=total > 0)
    return Assignment(labels, scores, a.votes.copy(), a.n_views.copy()), int(weak.sum())


def trusted_settings(cfg: AssignConfig, agreement: float) -> tuple[AssignConfig, bool]:
    """``cfg`` with the trusted-evidence settings when the masks agree enough
    (``cfg.trust_agreement``; ``agreement`` from
    :func:`~dcseg.assign.consistency.mask_agreement`), and whether they did. Trusted, no group
    of Gaussians is regrouped: each follows its own evidence in completion, and every Gaussian
    follows it after completion (``follow_evidence_ratio``).

    Example:
        >>> cfg = AssignConfig(trust_agreement=0.9)
        >>> trusted_settings(cfg, 0.95)[1], trusted_settings(cfg, 0.5)[1]
        (True, False)
    """
    if cfg.trust_agreement is None or not agreement >= cfg.trust_agreement:
        return cfg, False
    trusted = replace(
        cfg, min_share_ratio=cfg.trusted_share_ratio, evidence_weight=cfg.trusted_evidence_weight,
        regroup_min_gaussians=0, follow_evidence_ratio=cfg.trusted_follow_ratio,
    )  # fmt: skip
    return trusted, True


def drop_inconsistent(
    evidence: NDArray[np.float64],
    clustering: Clustering,
    assignment: Assignment,
    geometry: Geometry,
    cfg: AssignConfig,
) -> tuple[Clustering, Assignment]:
    """Gaussians contradicted by their own class evidence become noise; empty clusters go.

    ``agree`` (evidence for the Gaussian's cluster class) and ``total`` (for any class) are
    read off ``evidence`` (summed with the first cluster maps): the sums that
    :func:`dcseg.segment.class_agreement` makes in a pass of its own. Touching groups of at
    least ``cfg.regroup_min_gaussians`` of the Gaussians that left one cluster become
    clusters of their own (:func:`regroup_rejected`). The clusters are numbered ``0..K'-1``
    again and the assignment's arrays follow them.
    """
    classes = label_map(clustering.labels, assignment.labels)
    own = evidence[np.arange(len(classes)), np.maximum(classes, 0)]
    agree = np.where(classes >= 0, own, 0.0)
    total = evidence.sum(axis=1)
    drop = inconsistent(clustering.labels, classes, agree, total, cfg.min_share_ratio)
    origin = np.where(drop, clustering.labels, -1)
    labels = np.where(drop, -1, clustering.labels)
    kept = Clustering(labels, clustering.centers, clustering.scores)
    if cfg.regroup_min_gaussians > 0 and geometry[2] > 0 and drop.any():
        kept, assignment = regroup_rejected(kept, assignment, origin, evidence, geometry, cfg)
    used = np.bincount(kept.labels[kept.labels >= 0], minlength=kept.n_clusters) > 0
    compact, centers = compact_labels(kept.labels, kept.centers)
    a = assignment
    kept_assignment = Assignment(a.labels[used], a.scores[used], a.votes[used], a.n_views[used])
    return Clustering(compact, centers, clustering.scores.copy()), kept_assignment


def regroup_rejected(
    clustering: Clustering,
    assignment: Assignment,
    origin: NDArray[np.int64],
    evidence: NDArray[np.float64],
    geometry: Geometry,
    cfg: AssignConfig,
) -> tuple[Clustering, Assignment]:
    """``clustering`` and ``assignment`` with each touching group of Gaussians that left one
    cluster (``origin``; :func:`~dcseg.assign.consistency.rejected_groups`) appended as a
    cluster: its centre is its Gaussians' mean feature (unit norm), its class the one its
    pooled evidence supports most, its score that class's share of the pooled evidence; it
    has no IoU votes (``votes`` row 0, ``n_views`` 0). Groups of a stuff class stay noise
    (completion gives them their neighbours' class): at heavy noise they were pieces of
    tables whose confused evidence said floor, and became 50-Gaussian "floor" regions.
    Groups under ``cfg.regroup_min_gaussians`` but of at least
    ``cfg.regroup_unanimous_gaussians`` join them when their pooled evidence is (nearly)
    unanimous (share >= ``cfg.regroup_unanimous_share``)."""
    features, means, radius, stuff = geometry
    least = cfg.regroup_min_gaussians
    if cfg.regroup_unanimous_gaussians > 0:
        least = min(least, cfg.regroup_unanimous_gaussians)
    groups = rejected_groups(means, origin, evidence, radius, least)
    sizes = np.bincount(groups.ids[groups.ids >= 0], minlength=len(groups.classes))
    big = (sizes >= cfg.regroup_min_gaussians) | (groups.shares >= cfg.regroup_unanimous_share)
    groups = groups.only(big & ~np.isin(groups.classes, stuff))
    g = len(groups.classes)
    if g == 0:
        return clustering, assignment
    member = groups.ids >= 0
    feats = as_numpy(features, np.float64)[member]
    centers = np.zeros((g, feats.shape[1]))
    np.add.at(centers, groups.ids[member], feats)
    centers /= np.maximum(np.linalg.norm(centers, axis=1, keepdims=True), 1e-12)
    k = clustering.n_clusters
    labels = np.where(member, k + groups.ids, clustering.labels)
    all_centers = np.concatenate([clustering.centers, centers.astype(np.float32)])
    a = assignment
    grown = Assignment(
        np.concatenate([a.labels, groups.classes]),
        np.concatenate([a.scores, groups.shares]),
        np.concatenate([a.votes, np.zeros((g, a.votes.shape[1]))]),
        np.concatenate([a.n_views, np.zeros(g, dtype=np.int64)]),
    )
    return Clustering(labels, all_centers, clustering.scores), grown
