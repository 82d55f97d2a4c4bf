"""The job's stages, declared once: validate -> reconstruct -> train -> segment.

:func:`dcseg.jobs.run_job` runs :data:`STAGES` in one process (``dcseg run``, the Python API);
the worker runs the same entries one by one, committing each stage's folder, and reuses a
parent job's folder when the stage's key (:func:`key_of`) is unchanged. ``dcseg reconstruct``
runs the reconstruct stage alone, ``dcseg recluster`` / ``reclassify`` the segment stage on an
existing run. How to add a stage: ``docs/architecture.md``.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from dcseg.config import JobConfig
from dcseg.stages.base import Clock, Handover, Stage, StageResult, StageRun, stage_key
from dcseg.stages.reconstruct import RECONSTRUCT
from dcseg.stages.segment import SEGMENT
from dcseg.stages.train import TRAIN
from dcseg.stages.validate import VALIDATE

STAGES: tuple[Stage, ...] = (VALIDATE, RECONSTRUCT, TRAIN, SEGMENT)
"""The stages of a job, in the order they run."""

BY_NAME: dict[str, Stage] = {stage.name: stage for stage in STAGES}


def key_of(stage: Stage, config: JobConfig, digests: Mapping[str, str | None]) -> dict[str, Any]:
    """What ``stage``'s output depends on (:func:`dcseg.stages.base.stage_key`)."""
    return stage_key(stage, config, digests, BY_NAME)


__all__ = [
    "BY_NAME",
    "RECONSTRUCT",
    "SEGMENT",
    "STAGES",
    "TRAIN",
    "VALIDATE",
    "Clock",
    "Handover",
    "Stage",
    "StageResult",
    "StageRun",
    "key_of",
]
