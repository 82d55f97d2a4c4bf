"""The assignment stage's entry point: per-view cluster maps + class maps -> cluster labels."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dcseg.assign.config import AssignConfig
from dcseg.assign.confusion import unanimous_share, undo_confusions, view_counts
from dcseg.assign.masks import component_counts, mask_iou
from dcseg.assign.matching import Match, match_view
from dcseg.assign.vote import decide, tally


@dataclass(frozen=True)
class Assignment:
    """Class labels of K clusters (arrays are read-only).

    Attributes:
        labels: ``[K]`` int64 class index per cluster, -1 = never matched (unlabelled).
        scores: ``[K]`` float64 winning class's share of the cluster's summed IoU votes,
            0 when unlabelled.
        votes: ``[K, C]`` float64 IoU of every matched (cluster, class) pair summed over views.
        n_views: ``[K]`` int64 number of views in which the cluster was matched to a class.
        unanimous: share of the labelled clusters that every matched view names alike
            (:func:`~dcseg.assign.confusion.unanimous_share`): a segmenter error there repeats
            in every view and no vote can undo it; NaN when not measured.
        confusions: clusters whose voted class was taken for a consistent confusion and
            replaced by their companion class (:mod:`dcseg.assign.confusion`).
    """

    labels: NDArray[np.int64]
    scores: NDArray[np.float64]
    votes: NDArray[np.float64]
    n_views: NDArray[np.int64]
    unanimous: float = float("nan")
    confusions: int = 0

    def __post_init__(self) -> None:
        for array in (self.labels, self.scores, self.votes, self.n_views):
            array.flags.writeable = False


def view_matches(
    cluster_ids: NDArray[Any],
    class_map: NDArray[Any],
    n_clusters: int,
    n_classes: int,
    cfg: AssignConfig,
) -> list[Match]:
    """Compute one view's IoU between cluster and class masks, and match.

    Args:
        cluster_ids: ``[H, W]`` int cluster id per pixel, -1 = none, already cleaned with the
            2D connected-component filter (:func:`~dcseg.assign.masks.clean_cluster_map`).
        class_map: ``[H, W]`` int class index per pixel, -1 = none.
        n_clusters: K.
        n_classes: C.
        cfg: the stage's parameters.

    Returns:
        The view's ``(cluster, class, iou)`` matches.
    """
    iou = mask_iou(cluster_ids, class_map, n_clusters, n_classes)
    counts = None
    if cfg.matcher == "assignment" and cfg.replicas == "components":
        counts = component_counts(class_map, n_classes, cfg.min_area)
    return match_view(iou, cfg, counts=counts)


def _matches_per_view(
    cluster_maps: Sequence[NDArray[Any]],
    class_maps: Sequence[NDArray[Any]],
    n_clusters: int,
    n_classes: int,
    cfg: AssignConfig,
) -> Iterator[list[Match]]:
    for i, (ids, classes) in enumerate(zip(cluster_maps, class_maps, strict=True)):
        if np.shape(ids) != np.shape(classes):
            raise ValueError(
                f"view {i}: cluster map {np.shape(ids)} and class map {np.shape(classes)} differ"
            )
        yield view_matches(ids, classes, n_clusters, n_classes, cfg)


def assign_labels(
    cluster_maps: Sequence[NDArray[Any]],
    class_maps: Sequence[NDArray[Any]],
    n_clusters: int,
    n_classes: int,
    cfg: AssignConfig,
) -> Assignment:
    """Label clusters with classes by per-view matching and IoU-weighted voting (§6, B.7).

    Per view: compute the ``[K, C]`` IoU of the (cleaned) cluster map with the class map and
    match (:func:`~dcseg.assign.matching.match_view`); then sum the matched IoUs per
    (cluster, class) over views and take the best class per cluster; with
    ``cfg.confusion_min_share > 0``, clusters voted a class that behaves like a consistent
    confusion take their companion class (:mod:`dcseg.assign.confusion`). Views
    are processed one at a time: memory is O(H x W + K x C).

    Args:
        cluster_maps: per view, ``[H, W]`` int cluster id per pixel (-1 = none): the argmax of
            rendered cluster weights above the mask threshold, cleaned with
            :func:`~dcseg.assign.masks.clean_cluster_map` (``cfg.min_area``).
        class_maps: per view, ``[H, W]`` int class index (-1 = none), e.g.
            ``SemanticMap.classes``; same sizes as the cluster maps.
        n_clusters: K.
        n_classes: C, the vocabulary size.
        cfg: the stage's parameters.

    Returns:
        :class:`Assignment` with ``labels [K]`` (-1 = unlabelled), ``scores [K]``,
        ``votes [K, C]``, ``n_views [K]``.

    Example:
        >>> ids = np.array([[0, 0, 1, 1], [0, 0, 1, 1]])
        >>> classes = np.array([[2, 2, 0, 0], [2, 2, 0, -1]])
        >>> assign_labels([ids], [classes], 2, 3, AssignConfig(min_area=0)).labels.tolist()
        [2, 0]
    """
    if len(cluster_maps) != len(class_maps):
        raise ValueError(f"{len(cluster_maps)} cluster maps but {len(class_maps)} class maps")
    views = list(_matches_per_view(cluster_maps, class_maps, n_clusters, n_classes, cfg))
    votes, n_views = tally(views, n_clusters, n_classes)
    labels, scores = decide(votes)
    counts = view_counts(views, n_clusters, n_classes)
    unanimous = unanimous_share(counts, labels)
    if cfg.confusion_min_share > 0 and n_classes > 0:
        voted = labels
        labels = undo_confusions(
            voted, counts, votes,
            cfg.confusion_min_share, cfg.confusion_min_views, cfg.confusion_min_iou_ratio,
            cfg.confusion_companion == "alone",
        )  # fmt: skip
        won = votes[np.arange(len(labels)), np.maximum(labels, 0)]
        total = votes.sum(axis=1)
        scores = np.divide(won, total, out=np.zeros_like(won), where=total > 0)
        return Assignment(labels, scores, votes, n_views, unanimous, int((labels != voted).sum()))
    return Assignment(labels, scores, votes, n_views, unanimous)
