"""The evaluation stage's entry point: per-scene point labels -> pooled metrics."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dcseg.evaluate.config import EvaluateConfig
from dcseg.evaluate.metrics import confusion, metrics_from_confusion
from dcseg.evaluate.replica import REPLICA_SPLIT

SPLITS: Mapping[str, Mapping[str, Sequence[int]]] = {"replica": REPLICA_SPLIT}
"""Named class splits selectable by :attr:`EvaluateConfig.split`."""


def evaluate_scenes(
    gt_labels: Sequence[NDArray[Any]],
    pred_labels: Sequence[NDArray[Any]],
    class_names: Sequence[str],
    cfg: EvaluateConfig,
) -> dict[str, Any]:
    """Metrics of predicted point labels, pooled over scenes (OpenNeRF protocol, Part B.10).

    One confusion matrix is accumulated over all scenes (ignored GT skipped, no prediction =
    a miss); per-class IoU/Acc, and means over the classes present in the pooled GT.

    Args:
        gt_labels: per scene, ``[P_s]`` int GT class per point, -1 = ignored.
        pred_labels: per scene, ``[P_s]`` int predicted class, -1 = no prediction (e.g. from
            :func:`~dcseg.evaluate.points.vote_projection` or
            :func:`~dcseg.evaluate.points.transfer_nearest`).
        class_names: the C class names.
        cfg: the stage's parameters (``cfg.split`` names a split in :data:`SPLITS`).

    Returns:
        The :func:`~dcseg.evaluate.metrics.metrics_from_confusion` dict, plus ``"confusion"``:
        the pooled ``[C, C + 1]`` matrix as nested lists.

    Example:
        >>> m = evaluate_scenes([np.array([0, 1, -1])], [np.array([0, -1, 1])], ["a", "b"],
        ...                     EvaluateConfig())
        >>> m["miou"], m["no_prediction"]
        (0.5, 1)
    """
    if len(gt_labels) != len(pred_labels):
        raise ValueError(f"{len(gt_labels)} GT scenes but {len(pred_labels)} predictions")
    if cfg.split is not None and cfg.split not in SPLITS:
        raise ValueError(f"unknown split {cfg.split!r}; known: {sorted(SPLITS)}")
    n = len(class_names)
    conf = np.zeros((n, n + 1), dtype=np.int64)
    for gt, pred in zip(gt_labels, pred_labels, strict=True):
        conf += confusion(gt, pred, n)
    split = SPLITS[cfg.split] if cfg.split is not None else None
    metrics = metrics_from_confusion(conf, class_names, split)
    metrics["confusion"] = conf.tolist()
    return metrics
