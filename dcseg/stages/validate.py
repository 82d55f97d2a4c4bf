"""The validate stage: every input read and cross-checked before any work is spent on it."""

from __future__ import annotations

from dcseg.errors import InputError
from dcseg.io.jsonfile import write_json
from dcseg.stages.base import Stage, StageResult, StageRun

REPORT = "report.json"


def validate(run: StageRun) -> StageResult:
    """Check every input (:func:`dcseg.io.validate.validate_inputs`); InputError lists every
    problem found, naming its file. Writes the summary to ``report.json``."""
    from dcseg.io.validate import validate_inputs

    run.progress("validate", 0.0, "reading inputs")
    with run.clock.phase("validate"):
        report = validate_inputs(run.inputs, run.config.capture)
    if report.problems:
        raise InputError(report.problems)
    write_json(run.out / REPORT, report.summary)
    frames = report.summary.get("capture", {}).get("frames")
    run.progress("validate", 1.0, f"{frames} frames OK")
    return StageResult("done", f"validate: {frames} frames OK")


VALIDATE = Stage(
    name="validate",
    needs=(),
    inputs=("capture", "agnostic_masks", "semantic_masks", "vocabulary", "ground_truth"),
    outputs=(REPORT,),
    config=("capture",),
    parts={"validate": 1.0},
    run=validate,
)
