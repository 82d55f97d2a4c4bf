"""The pipeline stages the worker runs, as adapters over the dcseg library.

Each stage reads the job's inputs, calls one dcseg entry function and writes its files into
the folder it is given. Heavy imports (torch) happen inside ``run``, in the worker process.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from worker.contract import input_layout
from worker.execute import Stage, StageContext, StageOutcome


def _write_json(path: Path, data: Any) -> None:
    path.write_text(json.dumps(data, indent=2, sort_keys=True, default=str), encoding="utf-8")


def job_configs(config: dict[str, Any]) -> tuple[Any, Any]:
    """The job's ``(PipelineConfig, CaptureOptions)`` from its stored preset and options, built
    by the one config builder the CLI and the API use (:func:`dcseg.options.build_config`);
    InputError names a bad field."""
    from dcseg.options import from_stored

    return from_stored(config)


class ValidateStage:
    """Re-check the inputs (they were checked at upload; the reader may have changed)."""

    name = "validate"

    def key(self, config: dict[str, Any]) -> dict[str, Any]:
        return {
            "capture": config.get("options", {}).get("capture", {}),
            "inputs": config.get("inputs"),
        }

    def run(self, ctx: StageContext, out: Path) -> StageOutcome:
        from dcseg.errors import InputError
        from dcseg.io.validate import InputPaths, validate_inputs

        ctx.progress(0.0, "validate: reading inputs")
        paths = InputPaths(**input_layout(ctx.input_root))
        report = validate_inputs(paths, job_configs(ctx.config)[1])
        if report.problems:
            raise InputError(report.problems)
        _write_json(out / "report.json", report.summary)
        frames = report.summary.get("capture", {}).get("frames")
        return StageOutcome("done", f"validate: {frames} frames OK")


class ReconstructStage:
    """Stage 1 of DCSEG: fit 3D Gaussians to the posed RGB-D frames (``scene.ply``)."""

    name = "reconstruct"

    def key(self, config: dict[str, Any]) -> dict[str, Any]:
        options = config.get("options", {})
        return {
            "preset": config.get("preset"),
            "capture": options.get("capture", {}),
            "reconstruct": options.get("reconstruct", {}),
            "budget": options.get("budget", {}),
            "capture_sha256": config.get("inputs", {}).get("capture"),
            "upload": config.get("inputs", {}).get("upload"),
        }

    def run(self, ctx: StageContext, out: Path) -> StageOutcome:
        from dcseg.reconstruct.job import reconstruct_job

        pipeline, options = job_configs(ctx.config)

        def on_progress(iteration: int, total: int, loss: float) -> None:
            message = f"reconstruct: step {iteration}/{total}, loss {loss:.4f}"
            ctx.progress(iteration / max(total, 1), message)

        report = reconstruct_job(
            ctx.input_root,
            options,
            pipeline.reconstruct,
            out,
            budget=pipeline.budget,
            device=ctx.settings.device,
            on_progress=on_progress,
            report_name="metrics.json",
            rules=pipeline.rules,
        )
        return StageOutcome("done", f"reconstruct: {report['gaussians']} Gaussians")


TRAIN_WEIGHTS = {"cache": 0.1, "affinity": 0.9}
"""Share of the train stage's time in each of the library's sub-stages."""

SEGMENT_WEIGHTS = {"cluster": 0.35, "masks": 0.2, "assign": 0.2, "refine": 0.25}
"""Share of the segment stage's time in each of the library's sub-stages."""


class TrainStage:
    """Stage 2 of DCSEG on the reconstructed scene: blend-weight caches and affinity features.

    A derived job reuses it (and so trains nothing) when the capture, the class-agnostic masks
    and the training options are unchanged: a new scale, matcher or class-aware masks only
    re-run the segment stage.
    """

    name = "train"

    def key(self, config: dict[str, Any]) -> dict[str, Any]:
        options = config.get("options", {})
        inputs = config.get("inputs") or {}
        return {
            "reconstruct": ReconstructStage().key(config),
            "affinity": options.get("affinity", {}),
            "seed": options.get("segment", {}).get("seed", 0),
            "agnostic_masks": inputs.get("agnostic_masks"),
            "upload": inputs.get("upload"),
        }

    def run(self, ctx: StageContext, out: Path) -> StageOutcome:
        from dcseg.errors import InputError
        from dcseg.jobs import RunInputs, train_job

        assert ctx.output_root is not None
        scene = ctx.output_root / "reconstruct" / "scene.ply"
        cfg, options = job_configs(ctx.config)
        try:
            inputs = RunInputs.from_bundle(ctx.input_root, scene=scene, capture_options=options)
        except InputError as error:  # a capture-only upload: reconstruct, nothing more
            return StageOutcome("skipped", f"train: {error.problems[0].reason}")
        progress = _weighted_progress(ctx, TRAIN_WEIGHTS)
        record = train_job(inputs, cfg, out, progress, device=ctx.settings.device)
        return StageOutcome("done", f"train: {record['seconds'].get('train', 0):.0f} s")


class SegmentStage:
    """Stages 3-6 of DCSEG from the trained state: clusters, classes, exports, metrics."""

    name = "segment"

    def key(self, config: dict[str, Any]) -> dict[str, Any]:
        inputs = config.get("inputs") or {}
        return {
            "train": TrainStage().key(config),
            "segment": config.get("options", {}).get("segment", {}),
            "inputs": {k: inputs.get(k) for k in ("semantic_masks", "vocabulary", "ground_truth")},
        }

    def run(self, ctx: StageContext, out: Path) -> StageOutcome:
        from dcseg.jobs import resegment_job

        assert ctx.output_root is not None
        trained = ctx.output_root / "train"
        if not (trained / "run.json").is_file():
            return StageOutcome("skipped", "segment: nothing was trained (no masks uploaded)")
        layout = input_layout(ctx.input_root)
        cfg, _ = job_configs(ctx.config)
        record = resegment_job(
            trained,
            out,
            scale=cfg.scale,
            matcher=cfg.assign.mode,
            label_maps=cfg.assign.maps_from,
            semantic_masks=layout["semantic_masks"],
            vocabulary=layout["vocabulary"],
            ground_truth=layout["ground_truth"],
            on_progress=_weighted_progress(ctx, SEGMENT_WEIGHTS),
        )
        counts = record["counts"]
        message = f"segment: {counts['clusters']} instances, {counts['labelled_clusters']} labelled"
        return StageOutcome("done", message)


def _weighted_progress(ctx: StageContext, weights: dict[str, float]) -> Any:
    order = list(weights)

    def report(stage: str, fraction: float, message: str) -> None:
        if stage not in weights:
            return
        done = sum(weights[s] for s in order[: order.index(stage)])
        ctx.progress(done + weights[stage] * fraction, f"{stage}: {message}")

    return report


def default_stages() -> list[Stage]:
    """The stages, in order."""
    return [ValidateStage(), ReconstructStage(), TrainStage(), SegmentStage()]
