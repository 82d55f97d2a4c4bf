"""Mask scores: a detector's ``score``, SAM's ``predicted_iou`` and ``stability_score``.

Where a format gives them (SAM JSON records, COCO annotations, ``.npz`` stacks), masks scoring
below :class:`MinScores` are dropped when they are read. The defaults keep every mask, and a
mask without a given score is never dropped for it. SAM's own ``amg.py`` already drops masks
below 0.88 / 0.95; raising these thresholds keeps only its most confident masks.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    from dcseg.affinity.config import AffinityConfig

__all__ = ["NPZ_SCORE_KEYS", "SCORE_FIELDS", "MinScores", "min_scores"]

SCORE_FIELDS = ("score", "predicted_iou", "stability_score")
"""The record fields read as scores (COCO results / Grounded-SAM, SAM ``amg.py``)."""

NPZ_SCORE_KEYS = {
    "scores": "score",
    "predicted_iou": "predicted_iou",
    "stability_score": "stability_score",
}
"""``.npz`` array names -> score field (``scores``, plural, as Grounded-SAM saves them)."""


@dataclass(frozen=True)
class MinScores:
    """The lowest score of each kind a mask must have to be kept (0 = keep all).

    Attributes:
        score: a detector's confidence (COCO results ``score``, ``.npz`` ``scores``).
        predicted_iou: SAM's predicted mask quality.
        stability_score: SAM's mask stability under threshold changes.
    """

    score: float = 0.0
    predicted_iou: float = 0.0
    stability_score: float = 0.0

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"{f.name} threshold must be in [0, 1], got {value}")

    def keeps(self, record: Mapping[str, Any]) -> tuple[bool, str]:
        """Whether a record passes, and the problem with one of its score fields ("" = none).

        A score field that is present must be a finite number.
        """
        keep = True
        for name in SCORE_FIELDS:
            if name not in record:
                continue
            value = record[name]
            if isinstance(value, bool) or not isinstance(value, int | float):
                return False, f"'{name}' must be a number, got {value!r}"
            if not math.isfinite(value):
                return False, f"'{name}' must be finite, got {value!r}"
            keep = keep and value >= getattr(self, name)
        return keep, ""

    def keeps_all(self, scores: Mapping[str, NDArray[Any]], count: int) -> NDArray[np.bool_]:
        """Which of ``count`` masks pass, given per-mask score arrays by field name."""
        keep = np.ones(count, dtype=np.bool_)
        for name, values in scores.items():
            keep &= np.asarray(values, dtype=np.float64) >= getattr(self, name)
        return keep


def min_scores(affinity: AffinityConfig) -> MinScores:
    """The thresholds a job sets (``affinity.min_mask_score``, ``affinity.min_predicted_iou``,
    ``affinity.min_stability_score``): the masks that train the affinity features."""
    return MinScores(
        affinity.min_mask_score, affinity.min_predicted_iou, affinity.min_stability_score
    )
