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

from typing import Any, NamedTuple

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


def follow_evidence(
    labels: NDArray[np.integer[Any]], evidence: NDArray[np.floating[Any]], min_ratio: float
) -> NDArray[np.int64]:
    """Gaussians whose own evidence gives their class too small a share take their best class.

    A Gaussian with evidence whose class (or none, -1) has an evidence share below
    ``min_ratio`` x the share of its best-supported class takes that class; Gaussians without
    evidence keep theirs. Used only when the class-aware masks are trusted
    (``AssignConfig.follow_evidence_ratio``), after adoption and completion, so that every
    Gaussian, not only the members of labelled clusters, follows near-perfect masks.

    Args:
        labels: ``[N]`` class per Gaussian, -1 = none.
        evidence: ``[N, C]`` class evidence per Gaussian.
        min_ratio: in [0, 1]; 0 changes nothing, 1 = the 3D vote wherever there is evidence.

    Example:
        >>> ev = np.array([[1.0, 3.0], [2.0, 2.1], [0.0, 0.0], [0.0, 1.0]])
        >>> follow_evidence(np.array([0, 0, 0, -1]), ev, 0.9).tolist()
        [1, 0, 0, 1]
    """
    if not 0.0 <= min_ratio <= 1.0:
        raise ValueError(f"min_ratio must be in [0, 1], got {min_ratio}")
    out = np.asarray(labels, dtype=np.int64).copy()
    ev = np.asarray(evidence, dtype=np.float64)
    if ev.ndim != 2 or out.shape != (len(ev),):
        raise ValueError(f"labels {out.shape} and evidence {ev.shape} must have N rows")
    padded = np.column_stack([ev, np.zeros(len(ev))])  # class -1 reads the zero column
    own = padded[np.arange(len(out)), out]
    best = ev.max(axis=1, initial=0.0)
    flip = (ev.sum(axis=1) > 0) & (own < min_ratio * best)
    out[flip] = ev[flip].argmax(axis=1)
    return out


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


def pooled_evidence(
    labels: NDArray[np.integer[Any]], evidence: NDArray[np.floating[Any]], k: int
) -> NDArray[np.float64]:
    """``[k, C]`` class evidence summed over the Gaussians of each group ``0..k-1`` (``labels``
    ``[N]``; -1 = in none).

    Example:
        >>> pooled_evidence(np.array([0, 1, 0, -1]), np.eye(4, 2), 2).tolist()
        [[1.0, 0.0], [0.0, 1.0]]
    """
    ids = np.asarray(labels, dtype=np.int64)
    ev = np.asarray(evidence, dtype=np.float64)
    out = np.zeros((k, ev.shape[1]))
    member = ids >= 0
    np.add.at(out, ids[member], ev[member])
    return out


def unsupported(
    pooled: NDArray[np.floating[Any]],
    assigned: NDArray[np.integer[Any]],
    min_support: float,
) -> NDArray[np.bool_]:
    """Which labelled clusters their own pooled class evidence does not support.

    A cluster's pooled evidence is its Gaussians' class evidence summed
    (:func:`pooled_evidence`). Its voted class is unsupported when that class gets less than
    ``min_support`` x the pooled evidence of the cluster's best-supported class. The vote
    matches whole cluster masks by IoU, and when a class's replicas per view are taken by
    bigger clusters, a surface cluster beside a small object can win the object's class in a
    few views and never its own: a 1300-Gaussian floor patch voted ``domino`` whose own
    evidence gives domino 0.3 % of its weight.

    Args:
        pooled: ``[K, C]`` pooled class evidence of every cluster.
        assigned: ``[K]`` class of every cluster, -1 = none (never unsupported).
        min_support: in [0, 1]; 0 = every vote stands.

    Returns:
        ``[K]`` bool.

    Example:
        >>> pooled = np.array([[0.1, 9.0], [3.0, 1.0]])
        >>> unsupported(pooled, np.array([0, 0]), 0.1).tolist()
        [True, False]
    """
    if not 0.0 <= min_support <= 1.0:
        raise ValueError(f"min_support must be in [0, 1], got {min_support}")
    ev = np.asarray(pooled, dtype=np.float64)
    classes = np.asarray(assigned, dtype=np.int64)
    if ev.ndim != 2 or classes.shape != (len(ev),):
        raise ValueError(f"pooled {ev.shape} and assigned {classes.shape} must be [K, C] and [K]")
    voted = ev[np.arange(len(classes)), np.maximum(classes, 0)]
    best = ev.max(axis=1, initial=0.0)
    weak: NDArray[np.bool_] = (classes >= 0) & (best > 0) & (voted < min_support * best)
    return weak


def spread(points: NDArray[np.floating[Any]], tail: float = 5.0) -> float:
    """Largest side of the box that holds ``points`` (``[M, 3]``) between their ``tail`` and
    ``100 - tail`` percentiles per axis: a cluster's size, blind to a few stray Gaussians.

    Example:
        >>> xyz = np.zeros((101, 3)); xyz[:, 0] = np.linspace(0.0, 2.0, 101); xyz[0, 1] = 50.0
        >>> round(spread(xyz), 2)
        1.8
    """
    xyz = np.asarray(points, dtype=np.float64)
    if xyz.ndim != 2 or xyz.shape[1] != 3 or len(xyz) == 0:
        raise ValueError(f"points must be [M, 3] with M >= 1, got {xyz.shape}")
    low, high = np.percentile(xyz, [tail, 100.0 - tail], axis=0)
    return float((high - low).max())


class Groups(NamedTuple):
    """Touching groups of Gaussians that left one cluster (:func:`rejected_groups`).

    Attributes:
        ids: ``[N]`` int64 group of every Gaussian, ``0..G-1``; -1 = in none.
        classes: ``[G]`` int64 the class each group's pooled evidence supports most.
        shares: ``[G]`` float64 that class's share of the group's pooled evidence.
    """

    ids: NDArray[np.int64]
    classes: NDArray[np.int64]
    shares: NDArray[np.float64]

    def only(self, keep: NDArray[np.bool_]) -> Groups:
        """The groups where ``keep`` (``[G]``) is true, renumbered ``0..``; the rest in none."""
        number = np.cumsum(keep) - 1
        inside = self.ids >= 0
        ids = np.full(len(self.ids), -1, dtype=np.int64)
        ids[inside] = np.where(keep[self.ids[inside]], number[self.ids[inside]], -1)
        return Groups(ids, self.classes[keep], self.shares[keep])


def rejected_groups(
    means: NDArray[np.floating[Any]],
    origin: NDArray[np.integer[Any]],
    evidence: NDArray[np.floating[Any]],
    radius: float,
    min_size: int,
) -> Groups:
    """Connected groups of Gaussians that one cluster's evidence test rejected, with a class.

    ``origin`` is the cluster a Gaussian left (-1 = it left none). Gaussians that left the same
    cluster, lie within ``radius`` of each other and whose own evidence supports the same
    class most are connected; a connected group of at least ``min_size`` with any evidence is
    kept and takes the class its pooled evidence supports most; the rest are in no group. Used
    after the consistency step (``AssignConfig.regroup_min_gaussians``): an object that the
    class-agnostic masks merged with its support leaves the support's cluster as one such
    group, and a mug standing on a tray that both left a table's cluster leaves as a group
    of its own beside the tray's.

    Args:
        means: ``[N, 3]`` Gaussian centres.
        origin: ``[N]`` int cluster each Gaussian left, -1 = none.
        evidence: ``[N, C]`` class evidence per Gaussian.
        radius: > 0; Gaussians closer than this touch.
        min_size: >= 1.

    Example:
        >>> means = np.array([[0.0, 0, 0], [0.1, 0, 0], [0.2, 0, 0], [5.0, 0, 0]])
        >>> ev = np.array([[0.0, 1.0], [0.2, 0.8], [0.4, 0.6], [1.0, 0.0]])
        >>> g = rejected_groups(means, np.array([0, 0, 0, 0]), ev, radius=0.15, min_size=2)
        >>> g.ids.tolist(), g.classes.tolist(), g.shares.round(2).tolist()
        ([0, 0, 0, -1], [1], [0.8])
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    src = np.asarray(origin, dtype=np.int64)
    points = np.asarray(means, dtype=np.float64)
    ev = np.asarray(evidence, dtype=np.float64)
    n = len(src)
    if points.shape != (n, 3) or ev.ndim != 2 or len(ev) != n or src.ndim != 1:
        raise ValueError(
            f"means {points.shape}, origin {src.shape} and evidence {ev.shape} must be "
            "[N, 3], [N] and [N, C]"
        )
    if radius <= 0 or min_size < 1:
        raise ValueError(f"radius must be > 0 and min_size >= 1, got {radius} and {min_size}")
    ids = np.full(n, -1, dtype=np.int64)
    rows = np.flatnonzero(src >= 0)
    if len(rows) < min_size:
        return Groups(ids, np.zeros(0, np.int64), np.zeros(0))
    pairs = cKDTree(points[rows]).query_pairs(radius, output_type="ndarray")
    top = ev[rows].argmax(axis=1)  # an object merged with its support leaves it beside
    a, b = pairs[:, 0], pairs[:, 1]  # other rejected pieces: each keeps to its own class
    pairs = pairs[(src[rows[a]] == src[rows[b]]) & (top[a] == top[b])]
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(rows),) * 2)
    _, comp = connected_components(graph, directed=False)
    pooled = pooled_evidence(comp, ev[rows], int(comp.max()) + 1)
    total = pooled.sum(axis=1)
    ids[rows] = comp
    shares = np.divide(pooled.max(axis=1), total, out=np.zeros_like(total), where=total > 0)
    every = Groups(ids, pooled.argmax(axis=1).astype(np.int64), shares)
    return every.only((np.bincount(comp) >= min_size) & (total > 0))
