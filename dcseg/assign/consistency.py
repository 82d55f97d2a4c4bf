"""Drop Gaussians that their own class-mask evidence contradicts from their labelled cluster.

A cluster's class is decided by votes over whole cluster masks, so a cluster that also holds a
few Gaussians of a neighbouring surface (a ring of floor around a ball, a floor patch whose
features resemble a toy's) labels them with its class: in 3D and in every view. Each such
Gaussian has its own evidence too — its blending weight over the pixels each class-aware map
gives each class (:func:`dcseg.segment.evidence.class_agreement`) — and when that evidence
gives the cluster's class a much smaller share than the cluster's Gaussians give it together,
the Gaussian leaves the cluster (becomes noise). Class noise that is per view (a whole object
mislabelled or unlabelled in some views) lowers the share of all of an object's Gaussians
alike, so they stay.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray


def inconsistent(
    cluster_labels: NDArray[np.integer[Any]],
    classes: NDArray[np.integer[Any]],
    agree: NDArray[np.floating[Any]],
    total: NDArray[np.floating[Any]],
    min_ratio: float,
) -> NDArray[np.bool_]:
    """Which Gaussians give their cluster's class a much smaller share than their cluster does.

    A Gaussian's share is ``agree / total``; its cluster's share is the same ratio of the sums
    over the cluster's Gaussians. A Gaussian is inconsistent when its share is below
    ``min_ratio`` x its cluster's. Relative, not absolute, so that a rare class, which the
    class-aware maps miss in most views, keeps its clusters: all of their Gaussians have a
    small share, and only the ones far below their cluster's go.

    Args:
        cluster_labels: ``[N]`` cluster of every Gaussian, -1 = noise.
        classes: ``[N]`` class of every Gaussian's cluster (-1 = none: never inconsistent).
        agree: ``[N]`` evidence for that class.
        total: ``[N]`` evidence for any class; a Gaussian with none is never inconsistent.
        min_ratio: in [0, 1]; 0 keeps everything.

    Returns:
        ``[N]`` bool.

    Example:
        >>> inconsistent(np.array([0, 0, 0, 1]), np.array([2, 2, 2, 3]),
        ...              np.array([0.8, 0.8, 0.1, 0.1]), np.ones(4), 0.5).tolist()
        [False, False, True, False]
    """
    if not 0.0 <= min_ratio <= 1.0:
        raise ValueError(f"min_ratio must be in [0, 1], got {min_ratio}")
    labels = np.asarray(cluster_labels, dtype=np.int64)
    shapes = {np.shape(a) for a in (labels, classes, agree, total)}
    if len(shapes) != 1 or labels.ndim != 1:
        raise ValueError(
            f"cluster_labels {labels.shape}, classes {np.shape(classes)}, agree "
            f"{np.shape(agree)} and total {np.shape(total)} must be equal 1-D shapes"
        )
    agree = np.asarray(agree, dtype=np.float64)
    total = np.asarray(total, dtype=np.float64)
    member = labels >= 0
    k = int(labels.max(initial=-1)) + 1
    pooled_agree = np.bincount(labels[member], weights=agree[member], minlength=k)
    pooled_total = np.bincount(labels[member], weights=total[member], minlength=k)
    cluster_share = np.divide(pooled_agree, pooled_total, out=np.zeros(k), where=pooled_total > 0)
    reference = np.where(member, cluster_share[np.maximum(labels, 0)] if k else 0.0, 0.0)
    low: NDArray[np.bool_] = (
        member & (np.asarray(classes) >= 0) & (total > 0) & (agree < min_ratio * reference * total)
    )
    return low


def mask_agreement(classes: NDArray[np.integer[Any]], evidence: NDArray[np.floating[Any]]) -> float:
    """How much of the labelled Gaussians' class evidence agrees with their cluster's class.

    ``sum over labelled Gaussians of evidence[g, class(g)] / sum of all their evidence``: near
    1 when the class-aware maps agree with the 3D clusters everywhere (noise-free masks),
    lower as per-view mistakes, coarse boundaries and confusions accumulate. NaN when no
    labelled Gaussian has evidence.

    Args:
        classes: ``[N]`` class of every Gaussian's cluster, -1 = none.
        evidence: ``[N, C]`` class evidence per Gaussian (:func:`dcseg.segment.class_evidence`).

    Example:
        >>> ev = np.array([[3.0, 1.0], [0.0, 2.0], [5.0, 5.0]])
        >>> mask_agreement(np.array([0, 1, -1]), ev)
        0.8333333333333334
    """
    labels = np.asarray(classes, dtype=np.int64)
    ev = np.asarray(evidence, dtype=np.float64)
    if ev.ndim != 2 or labels.shape != (len(ev),):
        raise ValueError(f"classes {labels.shape} and evidence {ev.shape} must have N rows")
    rows = np.flatnonzero((labels >= 0) & (labels < ev.shape[1]))
    total = float(ev[rows].sum())
    if total <= 0:
        return float("nan")
    return float(ev[rows, labels[rows]].sum() / total)
