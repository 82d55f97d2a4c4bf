"""Whole jobs over files: run, re-segment, evaluate (used by the CLI and the Python API).

A job is the stage list :data:`dcseg.stages.STAGES`; :func:`run_job` runs it in this process
and publishes the segment stage's folder as the run (:mod:`dcseg.io.run_output`), so a failed
job leaves nothing behind. :func:`resegment_job` runs the segment stage again on a finished
run (``recluster``, ``reclassify``). Nothing here prints; progress goes through
``on_progress`` (:data:`dcseg.progress.Progress`).
"""

from __future__ import annotations

import json
import logging
import shutil
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

from dcseg.config import JobConfig, PipelineConfig
from dcseg.errors import InputError
from dcseg.inputs import RunInputs
from dcseg.io.run_output import load_labels, load_run, publish, staging_dir
from dcseg.progress import Progress, quiet
from dcseg.sizes import SCALED
from dcseg.stages import RECONSTRUCT, SEGMENT, STAGES, Clock, Handover, Stage, StageResult, StageRun
from dcseg.stages.reconstruct import REPORT as RECONSTRUCT_REPORT
from dcseg.stages.segment import evaluate, view_size

log = logging.getLogger(__name__)

__all__ = [
    "RunInputs",
    "evaluate_job",
    "reconstruct_job",
    "resegment_job",
    "run_job",
    "run_stages",
    "stored_config",
]


def run_job(
    inputs: RunInputs,
    config: JobConfig,
    out: Path,
    on_progress: Progress = quiet,
    *,
    device: str = "auto",
) -> dict[str, Any]:
    """Validate, reconstruct (or take ``inputs.scene``), train, segment, evaluate; publish
    ``out``. Without class-aware masks and vocabulary the run is class-agnostic (objects
    without classes, instance metrics only).

    ``device`` (:func:`dcseg.devices.resolve_device`) is where reconstruction, the cache's
    projection and affinity training run; clustering and classification run on the host.

    Returns:
        The ``run.json`` record.
    """
    if inputs.agnostic_masks is None:
        raise InputError.single(str(inputs.capture), "no agnostic_masks given")
    if (inputs.semantic_masks is None) != (inputs.vocabulary is None):
        reason = "class-aware masks and a vocabulary go together (give both or neither)"
        raise InputError.single("semantic masks", reason)
    work = staging_dir(out)
    try:
        results = run_stages(STAGES, inputs, config, work, on_progress, device=device)
        skipped = [r.message for r in results.values() if r.status == "skipped"]
        if skipped:  # pragma: no cover - every input is given
            raise InputError.single(str(inputs.capture), "; ".join(skipped))
        publish(work / SEGMENT.name, out)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    on_progress("done", 1.0, f"wrote {out}")
    return _record(out)


def reconstruct_job(
    capture: Path,
    config: JobConfig,
    out: Path,
    on_progress: Progress = quiet,
    *,
    device: str = "auto",
    scene: Path | None = None,
) -> dict[str, Any]:
    """Run the reconstruct stage alone into ``out`` (``dcseg reconstruct``): ``scene.ply``,
    ``reconstruction.json`` and, when its cameras differ from the capture's, ``poses.json``.
    Returns the report. A bundle's ground truth (``gt/points.ply``) adds the geometry metrics
    to the report."""
    out.mkdir(parents=True, exist_ok=True)
    inputs = RunInputs.from_bundle(capture, scene=scene, complete=False)
    stage = StageRun(inputs, config, out, {}, on_progress, device)
    RECONSTRUCT.run(stage)
    return _record(out, RECONSTRUCT_REPORT)


def run_stages(
    stages: Sequence[Stage],
    inputs: RunInputs,
    config: JobConfig,
    work: Path,
    on_progress: Progress = quiet,
    *,
    device: str = "auto",
) -> dict[str, StageResult]:
    """Run ``stages`` in order in this process, each into ``work/<name>/``, handing their
    products over in memory; returns each stage's result."""
    clock, handover = Clock(), Handover()
    done: dict[str, Path] = {}
    results: dict[str, StageResult] = {}
    for stage in stages:
        folder = work / stage.name
        folder.mkdir(parents=True)
        run = StageRun(inputs, config, folder, dict(done), on_progress, device, clock, handover)
        results[stage.name] = stage.run(run)
        done[stage.name] = folder
    return results


def resegment_job(
    run: Path,
    out: Path,
    inputs: RunInputs | None = None,
    config: JobConfig | None = None,
    on_progress: Progress = quiet,
) -> dict[str, Any]:
    """Cluster and classify a trained run again; nothing is trained.

    Args:
        run: a run folder (from :func:`run_job`, the train stage or this function).
        out: the new output folder (not ``run``).
        inputs: new class-aware masks and vocabulary (``reclassify``), ground truth to
            evaluate against; None or unset fields keep the run's masks.
        config: the config to segment with (a new scale, matcher, label maps: built by
            :func:`dcseg.options.build_config` from :func:`stored_config`); None = the run's.
        on_progress: progress callback.
    """
    if out.resolve() == run.resolve():
        raise InputError.single(str(out), "the new output must not replace the run it derives from")
    config = config or JobConfig(stored_config(run))
    inputs = replace(inputs or RunInputs(capture=run), capture=run, agnostic_masks=None)
    work = staging_dir(out)
    try:
        stage = StageRun(inputs, config, work, {"train": run}, on_progress)
        SEGMENT.run(stage)
        publish(work, out)
    except BaseException:
        shutil.rmtree(work, ignore_errors=True)
        raise
    on_progress("done", 1.0, f"wrote {out}")
    return _record(out)


def evaluate_job(run: Path, gt_file: Path) -> dict[str, Any]:
    """Evaluate a finished run against ground truth; writes and returns ``metrics.json``."""
    from dcseg.io.ground_truth import read_ground_truth

    saved = load_run(run)
    gt = read_ground_truth(gt_file, len(saved.vocabulary))
    labels = load_labels(run, [v.name for v in saved.trained.views], size=view_size(saved))
    return evaluate(saved, labels, gt, stored_config(run), run)


def stored_config(run: Path) -> PipelineConfig:
    """The config a run ran with (its ``run.json``), every size-ruled value kept as it ran;
    retired fields are dropped with a warning."""
    if not (run / "run.json").is_file() or not (run / "state").is_dir():
        raise InputError.single(str(run), "not a dcseg run folder (no run.json and state/)")
    try:
        cfg, dropped = PipelineConfig.from_stored(_record(run)["config"])
    except (KeyError, TypeError, ValueError) as exc:
        reason = f"config cannot be read by this dcseg version: {exc}"
        raise InputError.single(str(run / "run.json"), reason) from exc
    if dropped:
        log.warning("%s: ignoring retired config fields %s", run, ", ".join(dropped))
    return replace(cfg, rules=replace(cfg.rules, fixed=SCALED))


def _record(folder: Path, name: str = "run.json") -> dict[str, Any]:
    return json.loads((folder / name).read_text(encoding="utf-8"))  # type: ignore[no-any-return]
