"""Stage: semantic metrics on ground-truth 3D points (method doc §7, Part B.10).

Entry point: :func:`evaluate_scenes`. Point predictors: :func:`vote_projection` (the paper's
protocol; :data:`naive_fusion` is the same function fed with class-aware 2D maps) and
:func:`transfer_nearest`. Replica's class table and split live in :mod:`dcseg.evaluate.replica`.
The exports are resolved lazily (PEP 562), so ``dcseg.evaluate.config`` imports nothing heavy.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from dcseg._lazy import lazy_exports
from dcseg.evaluate.config import EvaluateConfig

if TYPE_CHECKING:
    from dcseg.evaluate.metrics import class_scores, confusion, metrics_from_confusion
    from dcseg.evaluate.points import (
        naive_fusion,
        transfer_nearest,
        transfer_opaque,
        vote_projection,
    )
    from dcseg.evaluate.replica import (
        REPLICA_CLASS_NAMES,
        REPLICA_CLASSES,
        REPLICA_SPLIT,
        replica_labels_from_raw,
    )
    from dcseg.evaluate.stage import SPLITS, evaluate_scenes

__all__ = [
    "EvaluateConfig",
    "REPLICA_CLASSES",
    "REPLICA_CLASS_NAMES",
    "REPLICA_SPLIT",
    "SPLITS",
    "class_scores",
    "confusion",
    "evaluate_scenes",
    "metrics_from_confusion",
    "naive_fusion",
    "replica_labels_from_raw",
    "transfer_nearest",
    "transfer_opaque",
    "vote_projection",
]

_HOME = {
    "REPLICA_CLASSES": "dcseg.evaluate.replica",
    "REPLICA_CLASS_NAMES": "dcseg.evaluate.replica",
    "REPLICA_SPLIT": "dcseg.evaluate.replica",
    "SPLITS": "dcseg.evaluate.stage",
    "class_scores": "dcseg.evaluate.metrics",
    "confusion": "dcseg.evaluate.metrics",
    "evaluate_scenes": "dcseg.evaluate.stage",
    "metrics_from_confusion": "dcseg.evaluate.metrics",
    "naive_fusion": "dcseg.evaluate.points",
    "replica_labels_from_raw": "dcseg.evaluate.replica",
    "transfer_nearest": "dcseg.evaluate.points",
    "transfer_opaque": "dcseg.evaluate.points",
    "vote_projection": "dcseg.evaluate.points",
}

__getattr__, __dir__ = lazy_exports(__name__, _HOME, __all__)
