"""The job's stages as the worker runs them: each entry of :data:`dcseg.stages.STAGES`,
wrapped once, generically.

The library declares what each stage reads, writes and depends on; here a stage gets the
job's typed config (rebuilt from the stored options by the one config builder), its input
files from the extracted upload, the folders of the stages committed before it, and a
progress callback that folds its parts into one fraction. Heavy imports (torch) happen inside
``run``, in the worker process.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from dcseg.config import JobConfig
from dcseg.progress import weighted
from dcseg.stages import STAGES, Stage, StageRun, key_of
from jobstore.contract import input_layout
from worker.stage import Stage as WorkerStage
from worker.stage import StageContext, StageOutcome


def job_config(config: Mapping[str, Any]) -> JobConfig:
    """The job's typed config from its stored preset and options, built by the one config
    builder the CLI and the API use (:func:`dcseg.options.build_config`); InputError names a
    bad field."""
    from dcseg.options import from_stored

    return from_stored(config)


class LibraryStage:
    """One library stage, run in the worker: inputs from the upload, earlier stages' files
    from the job's output folder."""

    def __init__(self, stage: Stage) -> None:
        self.stage = stage
        self.name = stage.name

    def key(self, config: dict[str, Any]) -> dict[str, Any]:
        """The stage's key (:func:`dcseg.stages.key_of`) over the upload's input digests."""
        digests = dict(config.get("inputs") or {})
        return {"upload": digests.get("upload"), **key_of(self.stage, job_config(config), digests)}

    def run(self, ctx: StageContext, out: Path) -> StageOutcome:
        from dcseg.inputs import RunInputs

        assert ctx.output_root is not None or not self.stage.needs
        layout = input_layout(ctx.input_root)
        inputs = RunInputs(**layout)
        done = {name: _folder(ctx, name) for name in self.stage.needs}
        progress = weighted(ctx.progress, self.name, self.stage.parts)
        run = StageRun(inputs, job_config(ctx.config), out, done, progress, ctx.settings.device)
        result = self.stage.run(run)
        return StageOutcome(result.status, result.message)


def _folder(ctx: StageContext, name: str) -> Path:
    assert ctx.output_root is not None
    return ctx.output_root / name


def default_stages() -> list[WorkerStage]:
    """The stages, in order."""
    return [LibraryStage(stage) for stage in STAGES]
