"""Label completion: unlabelled Gaussians on labelled surfaces take a class.

After classification, Gaussians that are noise (outside every cluster, or dropped by the 3D
outlier and consistency filters) or sit in clusters no view labelled carry no class, and a
ground-truth point whose nearest Gaussian is one of them gets no prediction. Each such Gaussian
with labelled Gaussians among its nearest neighbours (within the contact radius) takes the
class that maximises

    share of its labelled neighbours with that class + evidence_weight x its own evidence share

where its own evidence is its blending weight summed per class over the class-aware maps of all
views (:func:`class_evidence`). A few rounds let labels reach one neighbourhood further each
time; Gaussians with no labelled neighbour stay unlabelled (floaters are not labelled).

Given each Gaussian's footprint (its largest scale), a labelled Gaussian is also a neighbour
when the two footprints overlap (centres closer than the sum of the footprints), however far
apart their centres are against the contact radius: flat discs on walls and floors (surface
priors) are few and wide, several contact radii apart, and a disc dropped as a 3D outlier sat
unlabelled though it overlapped its labelled neighbours (:func:`reachable`).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree


def neighbour_shares(
    labels: NDArray[np.int64], idx: NDArray[np.int64], n_classes: int
) -> NDArray[np.float64]:
    """``[M, C]`` share of each query's found neighbours (``idx``, missing = ``len(labels)``)
    per class; all-zero rows for queries without a labelled neighbour."""
    m, k = idx.shape
    padded = np.append(labels, -1)
    classes = padded[np.minimum(idx, len(labels))]
    valid = classes >= 0
    rows = np.repeat(np.arange(m), k).reshape(m, k)
    counts = np.zeros((m, n_classes))
    np.add.at(counts, (rows[valid], classes[valid]), 1.0)
    found = counts.sum(axis=1, keepdims=True)
    out: NDArray[np.float64] = np.divide(counts, found, out=np.zeros_like(counts), where=found > 0)
    return out


def reachable(
    known: NDArray[np.float64],
    todo: NDArray[np.float64],
    k: int,
    radius: float,
    footprints: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None,
) -> NDArray[np.int64]:
    """``[M, k]`` indices into ``known`` of the ``k`` nearest known points of each ``todo``
    point within reach (missing = ``len(known)``): within ``radius``, or with footprints
    ``(known_fp, todo_fp)`` also closer than the sum of the two footprints.

    Example:
        >>> known, todo = np.zeros((1, 3)), np.array([[1.0, 0, 0]])
        >>> reachable(known, todo, 1, 0.5).tolist()
        [[1]]
        >>> reachable(known, todo, 1, 0.5, (np.array([0.6]), np.array([0.6]))).tolist()
        [[0]]
    """
    if footprints is None:
        _, idx = cKDTree(known).query(todo, k=k, distance_upper_bound=radius)
        return np.asarray(idx, dtype=np.int64).reshape(len(todo), k)
    known_fp, todo_fp = footprints
    bound = max(radius, float(known_fp.max(initial=0.0) + todo_fp.max(initial=0.0)))
    dist, idx = cKDTree(known).query(todo, k=k, distance_upper_bound=bound)
    dist = np.asarray(dist, dtype=np.float64).reshape(len(todo), k)
    idx = np.asarray(idx, dtype=np.int64).reshape(len(todo), k)
    padded = np.append(known_fp, np.inf)
    reach = np.maximum(radius, todo_fp[:, None] + padded[np.minimum(idx, len(known))])
    return np.where(dist <= reach, idx, len(known))


def complete_labels(
    means: NDArray[np.floating[Any]],
    labels: NDArray[np.integer[Any]],
    evidence: NDArray[np.floating[Any]],
    *,
    radius: float,
    neighbours: int,
    rounds: int,
    evidence_weight: float,
    footprints: NDArray[np.floating[Any]] | None = None,
    background: NDArray[np.bool_] | None = None,
) -> NDArray[np.int64]:
    """Give unlabelled Gaussians next to labelled ones a class (see the module docstring).

    Args:
        means: ``[N, 3]`` Gaussian centres.
        labels: ``[N]`` class per Gaussian, -1 = none.
        evidence: ``[N, C]`` class evidence per Gaussian (blending weight summed per class).
        radius: neighbours farther than this are not looked at (world units, > 0).
        neighbours: nearest labelled Gaussians looked at per unlabelled one.
        rounds: completion passes (0 = none).
        evidence_weight: weight of the own evidence share (0 = neighbours only).
        footprints: ``[N]`` each Gaussian's largest scale (world units): overlapping
            footprints also reach (None = the radius only).
        background: ``[N]`` Gaussians that stay unlabelled (the class masks leave them
            unlabelled: ``AssignConfig.background_share``); None = none.

    Returns:
        ``[N]`` int64 classes; labelled Gaussians keep theirs.

    Example:
        >>> xyz = np.array([[0, 0, 0], [0.1, 0, 0], [5, 0, 0]], float)
        >>> complete_labels(xyz, np.array([2, -1, -1]), np.zeros((3, 3)), radius=0.5,
        ...                 neighbours=2, rounds=1, evidence_weight=1.0).tolist()
        [2, 2, -1]
    """
    xyz = np.asarray(means, dtype=np.float64).reshape(-1, 3)
    out = np.asarray(labels, dtype=np.int64).copy()
    ev = np.asarray(evidence, dtype=np.float64)
    if out.shape != (len(xyz),) or ev.ndim != 2 or len(ev) != len(xyz):
        raise ValueError(
            f"means {xyz.shape}, labels {out.shape} and evidence {ev.shape} must have N rows"
        )
    if radius <= 0:
        raise ValueError(f"radius must be > 0, got {radius}")
    fp = None if footprints is None else np.asarray(footprints, dtype=np.float64).reshape(-1)
    if fp is not None and fp.shape != (len(xyz),):
        raise ValueError(f"footprints must be [{len(xyz)}], got {fp.shape}")
    total = ev.sum(axis=1, keepdims=True)
    own = np.divide(ev, total, out=np.zeros_like(ev), where=total > 0)
    for _ in range(rounds):
        known, todo = np.flatnonzero(out >= 0), np.flatnonzero(out < 0)
        if background is not None:
            todo = todo[~background[todo]]
        if len(known) == 0 or len(todo) == 0:
            break
        k = min(neighbours, len(known))
        pair = None if fp is None else (fp[known], fp[todo])
        idx = reachable(xyz[known], xyz[todo], k, radius, pair)
        near = neighbour_shares(out[known], idx, ev.shape[1])
        reached = near.sum(axis=1) > 0
        if not reached.any():
            break
        score = near[reached] + evidence_weight * own[todo[reached]]
        out[todo[reached]] = score.argmax(axis=1)
    return out
