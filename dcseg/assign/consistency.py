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
