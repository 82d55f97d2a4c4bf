"""Independent generators of realistic 2D segmenter errors for ``dcseg synth --error-model``.

Each generator is one model of how real segmenters fail, built on a different mechanism, so
that a method tuned on one can be measured on another (``../shared/docs/evaluation.md``):

* ``realistic`` (:mod:`.realistic`): open-vocabulary class maps with look-alike confusions in
  most views, swallowed small objects, 1/4-resolution maps; SAM masks with merges of touching
  objects and 10-30 % of the objects uncovered per view (the ``realistic`` noise level);
* ``detector`` (:mod:`.detector`): detector boxes prompting SAM: per-object classes confused by
  appearance and size, coarse dilated masks bleeding into neighbours at the same depth, small
  objects missed in every view, confidences attached, unlabelled where nothing was detected;
* ``lowres`` (:mod:`.lowres`): a closed-set semantic segmenter at 1/8 resolution with a fixed
  confusion matrix applied per instance in every view, never abstaining; SAM everything at 1/4
  resolution merging adjacent same-depth objects and leaving low-contrast objects uncovered.

Every generator uses the vocabulary :data:`~dcseg.synth.failures.REALISTIC_VOCABULARY`.
"""

from __future__ import annotations

from collections.abc import Callable

from dcseg.synth.errors.base import ErrorModel, SceneTruth, ViewOutput, ViewTruth
from dcseg.synth.errors.detector import DetectorModel
from dcseg.synth.errors.lowres import LowResModel
from dcseg.synth.errors.realistic import RealisticModel

ERROR_MODELS: dict[str, Callable[[], ErrorModel]] = {
    "realistic": RealisticModel,
    "detector": DetectorModel,
    "lowres": LowResModel,
}
"""Generator name -> a factory of the generator with its default parameters."""


def error_model(name: str) -> ErrorModel:
    """The generator called ``name``.

    Raises:
        ValueError: ``name`` is not in :data:`ERROR_MODELS` (the message lists them).
    """
    if name not in ERROR_MODELS:
        raise ValueError(f"error_model must be one of {sorted(ERROR_MODELS)}, got {name!r}")
    return ERROR_MODELS[name]()


__all__ = ["ERROR_MODELS", "ErrorModel", "SceneTruth", "ViewOutput", "ViewTruth", "error_model"]
