"""IoU-weighted votes of matched (cluster, class) pairs, summed over views."""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:  # annotations only: matching imports scipy, this module stays light
    from dcseg.assign.matching import Match


def tally(
    per_view_matches: Iterable[Sequence[Match]], n_clusters: int, n_classes: int
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Sum the IoU of every matched pair over views.

    Args:
        per_view_matches: for each view, its ``(cluster, class, iou)`` matches.
        n_clusters: K.
        n_classes: C.

    Returns:
        ``votes [K, C]`` float64 summed IoU and ``n_views [K]`` int64, the number of views in
        which each cluster was matched.
    """
    votes = np.zeros((n_clusters, n_classes), dtype=np.float64)
    n_views = np.zeros(n_clusters, dtype=np.int64)
    for matches in per_view_matches:
        for cluster, cls, iou in matches:
            votes[cluster, cls] += iou
            n_views[cluster] += 1
    return votes, n_views


def decide(votes: NDArray[np.float64]) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Each cluster's class from its votes.

    Args:
        votes: ``[K, C]`` summed IoU votes.

    Returns:
        ``labels [K]`` int64: the class with the largest summed IoU, ties -> the lowest class
        index (``argmax`` order), -1 when the cluster has no vote; ``scores [K]`` float64: the
        winner's share of the cluster's total vote, in (0, 1], 0 when unvoted.
    """
    total = votes.sum(axis=1)
    if votes.shape[1] == 0:
        return np.full(len(votes), -1, dtype=np.int64), np.zeros(len(votes))
    labels = np.where(total > 0, votes.argmax(axis=1), -1).astype(np.int64)
    best = votes.max(axis=1)
    scores = np.divide(best, total, out=np.zeros_like(best), where=total > 0)
    return labels, scores


def vote(
    per_view_matches: Iterable[Sequence[Match]], n_clusters: int, n_classes: int
) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Label clusters by IoU-weighted votes summed over views (see :func:`decide`).

    Args:
        per_view_matches: for each view, its ``(cluster, class, iou)`` matches.
        n_clusters: K.
        n_classes: C.

    Returns:
        ``labels [K]`` (-1 = unvoted; ties -> lowest class index) and ``scores [K]``.
    """
    votes, _ = tally(per_view_matches, n_clusters, n_classes)
    return decide(votes)
