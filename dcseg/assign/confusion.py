"""Undo a segmenter's consistent class confusions with the views that name the object right.

Real segmenters mistake an object for a look-alike (a ball for a globe, a table for a desk) in
most views, not all: the vote over views then elects the look-alike, and naive 2D fusion does
the same. The views that name the object right are a minority, but a telling one when the
scene is looked at as a whole (a Dawid-Skene-style argument over all clusters): if every
cluster that the vote gives class ``y`` is also named some other class ``x`` in a steady share
of its views, with masks that cover it as well as ``y``'s do (the whole object renamed, not a
neighbour bleeding in), and ``y`` is never named alone, then ``y`` behaves like a confusion of
its companions, not like a class of its own, and each of those clusters takes its companion.
A class that some cluster shows without a companion is a real class, and its clusters keep it;
an object named wrong in every view has no companion, and no vote can undo that
(``benchmarks/error_model_stats.py`` measures how many such objects a scene has).

The argument is not symmetric by itself: a segmenter that confuses objects in some views at
random (a ball named bowl in a third of its views, every ball alike) makes the right class
look just as dependent, with a companion that is the confusion. Per cluster the two cannot
be told apart: one companion, rarely a third name, whole-object masks, and shares that
overlap (``benchmarks/confusion_gate_stats.py``: look-alike companions 0.17-0.43 of the views,
per-view noise 0.17-0.41). ``companion_alone`` (:func:`named_alone`) asks the same question of
the companion: it is taken only when the scene names it alone for some other object; a
companion that is itself only ever a minority name behaves like a confusion as much as the
voted class does, and the vote stands. On the measured layouts that kept out every relabel
random per-view noise made wrong, and lost those of objects whose true class no other object
shows (``benchmarks/results/confusion_gate.json``).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    from dcseg.assign.matching import Match


def view_counts(
    per_view_matches: Iterable[Sequence[Match]], n_clusters: int, n_classes: int
) -> NDArray[np.int64]:
    """``[K, C]`` int64: in how many views each cluster was matched to each class."""
    counts = np.zeros((n_clusters, n_classes), dtype=np.int64)
    for matches in per_view_matches:
        for cluster, cls, _ in matches:
            counts[cluster, cls] += 1
    return counts


def companions(
    labels: NDArray[np.integer[Any]],
    counts: NDArray[np.integer[Any]],
    votes: NDArray[np.floating[Any]],
    min_share: float,
    min_views: int,
    min_iou_ratio: float,
) -> NDArray[np.int64]:
    """Each labelled cluster's companion class: the other class it is matched to most often,
    when that is in at least ``min_views`` views and ``min_share`` of its matched views, and
    its mean matched IoU is at least ``min_iou_ratio`` x that of the cluster's own class.

    Args:
        labels: ``[K]`` voted class per cluster, -1 = none.
        counts: ``[K, C]`` views matched per (cluster, class) (:func:`view_counts`).
        votes: ``[K, C]`` summed IoU per (cluster, class).
        min_share: in (0, 1].
        min_views: >= 1.
        min_iou_ratio: >= 0.

    Returns:
        ``[K]`` int64 companion class, -1 = none.

    Example:
        >>> counts = np.array([[16, 4, 0], [20, 0, 1]])
        >>> votes = np.array([[12.0, 3.0, 0.0], [15.0, 0.0, 0.1]])
        >>> companions(np.array([0, 0]), counts, votes, 0.1, 2, 0.5).tolist()
        [1, -1]
    """
    labels = np.asarray(labels, dtype=np.int64)
    n = np.asarray(counts, dtype=np.float64)
    iou = np.divide(votes, n, out=np.zeros_like(n), where=n > 0)
    out = np.full(len(labels), -1, dtype=np.int64)
    for k in np.flatnonzero(labels >= 0):
        own = labels[k]
        others = n[k].copy()
        others[own] = 0.0
        x = int(others.argmax()) if len(others) else -1
        if x < 0 or others[x] < max(min_views, min_share * n[k].sum()):
            continue
        if iou[k, x] >= min_iou_ratio * iou[k, own]:
            out[k] = x
    return out


def dependent_classes(
    labels: NDArray[np.integer[Any]],
    companion: NDArray[np.integer[Any]],
    counts: NDArray[np.integer[Any]],
    min_tested: int,
) -> NDArray[np.bool_]:
    """``[C]`` bool: classes that every tested cluster voted them has a companion for.

    A cluster is tested when it was matched in at least ``min_tested`` views (fewer cannot show
    a companion); a class with no tested cluster is not dependent.

    Example:
        >>> counts = np.array([[20, 5], [24, 0], [3, 0]])
        >>> dependent_classes(np.array([0, 1, 0]), np.array([1, -1, -1]), counts, 10).tolist()
        [True, False]
    """
    labels = np.asarray(labels, dtype=np.int64)
    tested = _tested(labels, counts, min_tested)
    voted = np.bincount(labels[tested], minlength=np.shape(counts)[1])
    dependent: NDArray[np.bool_] = (voted > 0) & ~named_alone(labels, companion, counts, min_tested)
    return dependent


def _tested(
    labels: NDArray[np.integer[Any]], counts: NDArray[np.integer[Any]], min_tested: int
) -> NDArray[np.bool_]:
    """``[K]`` bool: labelled clusters matched in at least ``min_tested`` views."""
    tested: NDArray[np.bool_] = (labels >= 0) & (np.asarray(counts).sum(axis=1) >= min_tested)
    return tested


def named_alone(
    labels: NDArray[np.integer[Any]],
    companion: NDArray[np.integer[Any]],
    counts: NDArray[np.integer[Any]],
    min_tested: int,
) -> NDArray[np.bool_]:
    """``[C]`` bool: classes that some tested cluster is voted with no companion, i.e. that
    the segmenter names alone for some object of the scene (tested as in
    :func:`dependent_classes`).

    Example:
        >>> counts = np.array([[20, 5, 0], [0, 24, 0], [0, 4, 20]])
        >>> named_alone(np.array([0, 1, 2]), np.array([1, -1, 1]), counts, 10).tolist()
        [False, True, False]
    """
    labels = np.asarray(labels, dtype=np.int64)
    lone = _tested(labels, counts, min_tested) & (np.asarray(companion) < 0)
    alone: NDArray[np.bool_] = np.bincount(labels[lone], minlength=np.shape(counts)[1]) > 0
    return alone


def undo_confusions(
    labels: NDArray[np.integer[Any]],
    counts: NDArray[np.integer[Any]],
    votes: NDArray[np.floating[Any]],
    min_share: float,
    min_views: int,
    min_iou_ratio: float,
    companion_alone: bool = False,
) -> NDArray[np.int64]:
    """Clusters voted a class that behaves like a confusion take their companion class.

    With ``companion_alone``, only a companion that the scene also names alone
    (:func:`named_alone`) is taken: a companion that is itself only ever a minority name
    behaves like a confusion as much as the voted class does, and the vote stands.

    See the module docstring; :func:`companions` and :func:`dependent_classes` (tested
    clusters: matched in at least ``ceil(min_views / min_share)`` views).

    Returns:
        ``[K]`` int64 labels; unchanged where the voted class is not dependent.

    Example:
        >>> counts = np.array([[19, 5, 0], [0, 24, 0], [0, 4, 20]])
        >>> votes = counts * 0.7
        >>> undo_confusions(np.array([0, 1, 2]), counts, votes, 0.1, 2, 0.5).tolist()
        [1, 1, 1]
    """
    if not 0.0 < min_share <= 1.0 or min_views < 1:
        raise ValueError(f"need min_share in (0, 1] and min_views >= 1: {min_share}, {min_views}")
    out = np.asarray(labels, dtype=np.int64).copy()
    if np.shape(counts)[1] == 0:  # no vocabulary (a class-agnostic run): nothing voted
        return out
    companion = companions(out, counts, votes, min_share, min_views, min_iou_ratio)
    min_tested = math.ceil(min_views / min_share)
    dependent = dependent_classes(out, companion, counts, min_tested)
    flip = (out >= 0) & (companion >= 0) & dependent[np.maximum(out, 0)]
    if companion_alone:
        flip &= named_alone(out, companion, counts, min_tested)[np.maximum(companion, 0)]
    out[flip] = companion[flip]
    return out


def unanimous_share(counts: NDArray[np.integer[Any]], labels: NDArray[np.integer[Any]]) -> float:
    """Share of the labelled clusters whose every matched view names their class: where the
    segmenter is wrong about them, it is wrong in every view and no vote can tell (NaN when
    no cluster is labelled).

    Example:
        >>> unanimous_share(np.array([[5, 0], [4, 1], [0, 0]]), np.array([0, 0, -1]))
        0.5
    """
    labels = np.asarray(labels, dtype=np.int64)
    rows = np.flatnonzero(labels >= 0)
    if not len(rows):
        return float("nan")
    n = np.asarray(counts)[rows]
    return float(np.mean(n[np.arange(len(rows)), labels[rows]] == n.sum(axis=1)))
