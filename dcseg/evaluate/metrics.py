"""Confusion matrix and OpenNeRF-style semantic metrics with a "no prediction" column."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray


def confusion(gt: NDArray[Any], pred: NDArray[Any], n_classes: int) -> NDArray[np.int64]:
    """Confusion matrix of per-point labels, with a last column for "no prediction".

    Args:
        gt: ``[P]`` int ground-truth class, -1 = ignored (the point is skipped).
        pred: ``[P]`` int predicted class, -1 = no prediction.
        n_classes: C.

    Returns:
        ``[C, C + 1]`` int64 counts; row = GT class, column = predicted class, column C = no
        prediction (a miss: counts as FN of the row's class, as FP of nothing).
    """
    gt = np.asarray(gt, dtype=np.int64).ravel()
    pred = np.asarray(pred, dtype=np.int64).ravel()
    if gt.shape != pred.shape:
        raise ValueError(f"gt has {gt.size} points but pred has {pred.size}")
    for name, values in (("gt", gt), ("pred", pred)):
        if values.size and (values.min() < -1 or values.max() >= n_classes):
            raise ValueError(f"{name} values must be in [-1, {n_classes}), got {values.max()}")
    keep = gt >= 0
    cols = np.where(pred[keep] >= 0, pred[keep], n_classes)
    flat = np.bincount(gt[keep] * (n_classes + 1) + cols, minlength=n_classes * (n_classes + 1))
    return flat.reshape(n_classes, n_classes + 1)


def _nanmean(values: NDArray[np.float64]) -> float:
    return float(values.mean()) if values.size else float("nan")


def class_scores(conf: NDArray[Any]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Per-class IoU = TP/(TP+FP+FN) and Acc = TP/(TP+FN) from a ``[C, C + 1]`` confusion.

    Classes that never occur in the ground truth get NaN for both.
    """
    conf = np.asarray(conf, dtype=np.float64)
    n = conf.shape[0]
    if conf.shape != (n, n + 1):
        raise ValueError(f"confusion must be [C, C + 1], got {conf.shape}")
    tp = np.diag(conf[:, :n])
    gt_count = conf.sum(axis=1)  # TP + FN, FN includes "no prediction"
    fp = conf[:, :n].sum(axis=0) - tp
    present = gt_count > 0
    nan = np.full(n, np.nan)
    iou = np.divide(tp, gt_count + fp, out=nan.copy(), where=present)
    acc = np.divide(tp, gt_count, out=nan.copy(), where=present)
    return iou, acc


def metrics_from_confusion(
    conf: NDArray[Any],
    class_names: Sequence[str],
    split: Mapping[str, Sequence[int]] | None = None,
) -> dict[str, Any]:
    """mIoU / mAcc over the classes present in the ground truth, per class and per split.

    To pool several scenes, sum their confusion matrices first (OpenNeRF protocol).

    Args:
        conf: ``[C, C + 1]`` confusion from :func:`confusion` (or a sum of several).
        class_names: C names, for the per-class entries.
        split: optional named groups of class indices (e.g. Replica head/common/tail).

    Returns:
        ``{"miou", "macc"}`` means over present classes (NaN if none);
        ``"iou"``, ``"acc"``: ``{name: value}`` (NaN for classes absent from the GT);
        ``"present"``: names of the classes occurring in the GT; ``"n_points"``: evaluated
        (non-ignored) points; ``"no_prediction"``: how many of them had no prediction;
        ``"splits"`` (only with ``split``): ``{group: {"miou", "macc", "n_present"}}``.
    """
    conf = np.asarray(conf)
    if len(class_names) != conf.shape[0]:
        raise ValueError(f"{len(class_names)} class names for a {conf.shape} confusion")
    iou, acc = class_scores(conf)
    present = ~np.isnan(iou)
    out: dict[str, Any] = {
        "miou": _nanmean(iou[present]),
        "macc": _nanmean(acc[present]),
        "iou": {name: float(v) for name, v in zip(class_names, iou, strict=True)},
        "acc": {name: float(v) for name, v in zip(class_names, acc, strict=True)},
        "present": [name for name, p in zip(class_names, present, strict=True) if p],
        "n_points": int(conf.sum()),
        "no_prediction": int(conf[:, -1].sum()),
    }
    if split is not None:
        out["splits"] = {
            group: _split_means(iou, acc, present, np.asarray(idx, dtype=np.int64))
            for group, idx in split.items()
        }
    return out


def _split_means(
    iou: NDArray[np.float64],
    acc: NDArray[np.float64],
    present: NDArray[np.bool_],
    idx: NDArray[np.int64],
) -> dict[str, Any]:
    sel = idx[present[idx]]
    return {"miou": _nanmean(iou[sel]), "macc": _nanmean(acc[sel]), "n_present": int(sel.size)}
