"""Instance metrics on ground-truth points: one-to-one matches at an IoU threshold.

Predicted instance ids reach the ground-truth points as the semantic labels do in the 3D
protocol (:func:`~dcseg.evaluate.points.transfer_nearest`). Ground-truth objects and predicted
instances with at least ``min_points`` points take part; every pair's IoU is counted on the
points, a Hungarian assignment maximises the summed IoU, and an assigned pair is a match when
its IoU reaches the threshold (``../shared/docs/evaluation.md``, instance metrics).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import linear_sum_assignment

MIN_POINTS = 50
"""Smallest number of points of a ground-truth object or predicted instance that is scored."""
IOU_THRESHOLD = 0.5
"""Smallest IoU of a one-to-one pair that counts as a match."""


def pair_iou(
    gt: NDArray[np.int64], pred: NDArray[np.int64], gt_ids: NDArray[np.int64],
    pred_ids: NDArray[np.int64],
) -> NDArray[np.float64]:  # fmt: skip
    """``[G, K]`` IoU on the points between each listed ground-truth object and prediction.

    Args:
        gt: ``[P]`` ground-truth instance per point (-1 = none).
        pred: ``[P]`` predicted instance per point (-1 = none).
        gt_ids: the G sorted ground-truth ids to score; pred_ids: the K sorted predicted ids.
    """
    g, k = _position(gt, gt_ids), _position(pred, pred_ids)
    both = (g >= 0) & (k >= 0)
    inter = np.zeros((len(gt_ids), len(pred_ids)))
    np.add.at(inter, (g[both], k[both]), 1.0)
    gt_size = np.bincount(g[g >= 0], minlength=len(gt_ids)).astype(np.float64)
    pred_size = np.bincount(k[k >= 0], minlength=len(pred_ids)).astype(np.float64)
    union = gt_size[:, None] + pred_size[None, :] - inter
    return np.divide(inter, union, out=np.zeros_like(inter), where=union > 0)


def _position(labels: NDArray[np.int64], ids: NDArray[np.int64]) -> NDArray[np.int64]:
    """Per point, the index of its label in the sorted ``ids``, -1 when it is not listed."""
    if len(ids) == 0:
        return np.full(labels.shape, -1, dtype=np.int64)
    at = np.minimum(np.searchsorted(ids, labels), len(ids) - 1)
    return np.where(ids[at] == labels, at, -1).astype(np.int64)


def instance_metrics(
    gt_instances: NDArray[Any],
    pred_instances: NDArray[Any],
    n_written: int | None = None,
    min_points: int = MIN_POINTS,
    iou_threshold: float = IOU_THRESHOLD,
) -> dict[str, Any]:
    """Precision, recall, F1 of one-to-one matches, mean best IoU per object, and counts.

    Args:
        gt_instances: ``[P]`` int ground-truth object per point, -1 = none (skipped).
        pred_instances: ``[P]`` int predicted instance per point, -1 = no prediction.
        n_written: the number of instances the run wrote (``instances.json``); None = the
            number of distinct predicted ids on the points.
        min_points: objects and instances with fewer points are left out.
        iou_threshold: smallest IoU of a match.

    Returns:
        ``{"precision", "recall", "f1", "mcov", "matches", "n_gt", "n_pred", "n_written",
        "count_ratio"}``: ``n_gt``/``n_pred`` count the scored objects and instances, ``mcov``
        is the mean over scored objects of their best IoU with any scored instance, and
        ``count_ratio`` is ``n_written / n_gt``. Precision, recall and F1 are fractions (NaN
        without any scored object or instance).

    Example:
        >>> m = instance_metrics(np.repeat([0, 1], 60), np.repeat([5, 5], 60))
        >>> m["matches"], m["recall"]
        (1, 0.5)
    """
    gt = np.asarray(gt_instances, dtype=np.int64).ravel()
    pred = np.asarray(pred_instances, dtype=np.int64).ravel()
    if gt.shape != pred.shape:
        raise ValueError(f"gt_instances has {gt.size} points but pred_instances has {pred.size}")
    if not 0.0 < iou_threshold <= 1.0:
        raise ValueError(f"iou_threshold must be in (0, 1], got {iou_threshold}")
    pred = np.where(gt >= 0, pred, -1)  # points without ground truth are not scored
    gt_ids = _ids_with(gt, min_points)
    pred_ids = _ids_with(pred, min_points)
    iou = pair_iou(gt, pred, gt_ids, pred_ids)
    rows, cols = linear_sum_assignment(iou, maximize=True)
    matches = int((iou[rows, cols] >= iou_threshold).sum())
    written = int(np.unique(pred[pred >= 0]).size) if n_written is None else int(n_written)
    precision = matches / len(pred_ids) if len(pred_ids) else float("nan")
    recall = matches / len(gt_ids) if len(gt_ids) else float("nan")
    denominator = len(pred_ids) + len(gt_ids)
    return {
        "precision": precision,
        "recall": recall,
        "f1": 2 * matches / denominator if denominator else float("nan"),
        "mcov": float(iou.max(axis=1, initial=0.0).mean()) if len(gt_ids) else float("nan"),
        "matches": matches,
        "n_gt": len(gt_ids),
        "n_pred": len(pred_ids),
        "n_written": written,
        "count_ratio": written / len(gt_ids) if len(gt_ids) else float("nan"),
    }


def _ids_with(labels: NDArray[np.int64], min_points: int) -> NDArray[np.int64]:
    """Sorted ids (>= 0) with at least ``min_points`` points."""
    ids, counts = np.unique(labels[labels >= 0], return_counts=True)
    return ids[counts >= min_points].astype(np.int64)
