"""Per-view bipartite matching of clusters to (replicated) classes with scipy's LSA solver."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import linear_sum_assignment

from dcseg.assign.config import AssignConfig

Match = tuple[int, int, float]
"""``(cluster, class, iou)`` of one matched edge."""


def class_replicas(
    n_classes: int, cfg: AssignConfig, counts: ArrayLike | None = None
) -> NDArray[np.int64]:
    """How many columns each class gets in the matching problem -> ``[C]`` int64.

    ``"matching"`` mode: 1 each. ``"assignment"`` mode: ``cfg.replicas`` each, or ``counts``
    (per-class connected-component counts of the view) when ``cfg.replicas == "components"``.
    """
    if cfg.matcher == "matching":
        return np.ones(n_classes, dtype=np.int64)
    if cfg.replicas == "components":
        if counts is None:
            raise ValueError("replicas='components' needs per-class component counts")
        per_class = np.asarray(counts, dtype=np.int64)
        if per_class.shape != (n_classes,) or np.any(per_class < 0):
            raise ValueError(f"counts must be [{n_classes}] and >= 0, got {per_class}")
        return per_class
    return np.full(n_classes, cfg.replicas, dtype=np.int64)


def match_view(
    iou: NDArray[Any], cfg: AssignConfig, *, counts: ArrayLike | None = None
) -> list[Match]:
    """Match clusters to classes in one view: most valid edges first, then most total IoU.

    Each class column is replicated (see :func:`class_replicas`) so a class can take several
    clusters. Edges with IoU < ``cfg.min_iou`` are invalid. Weights are ``IoU + B`` on valid
    edges and 0 elsewhere, with ``B = min(K, R) + 1`` larger than any achievable IoU sum, so
    maximising the total weight with ``scipy.optimize.linear_sum_assignment`` maximises the
    number of valid edges first and total IoU second (the networkx
    ``max_weight_matching(maxcardinality=True)`` objective of the paper code). Pairs on
    invalid edges are dropped after solving.

    Args:
        iou: ``[K, C]`` IoU of cluster masks with class masks in this view.
        cfg: mode, replicas and IoU floor.
        counts: ``[C]`` per-class component counts; needed when ``cfg.replicas ==
            "components"`` (see :func:`~dcseg.assign.masks.component_counts`).

    Returns:
        Matched ``(cluster, class, iou)`` triples sorted by cluster; each cluster at most once.
    """
    iou = np.asarray(iou, dtype=np.float64)
    if iou.ndim != 2:
        raise ValueError(f"iou must be [K, C], got shape {iou.shape}")
    column_class = np.repeat(np.arange(iou.shape[1]), class_replicas(iou.shape[1], cfg, counts))
    weights = iou[:, column_class]
    valid = weights >= cfg.min_iou
    if not valid.any():
        return []
    bonus = min(weights.shape) + 1.0
    rows, cols = linear_sum_assignment(np.where(valid, weights + bonus, 0.0), maximize=True)
    keep = valid[rows, cols]
    return [
        (int(r), int(column_class[c]), float(iou[r, column_class[c]]))
        for r, c in zip(rows[keep], cols[keep], strict=True)
    ]
