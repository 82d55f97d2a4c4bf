"""The pipeline stages the worker runs, as adapters over the dcseg library.

Each stage reads the job's inputs, calls one dcseg entry function and writes its files into
the folder it is given. Heavy imports (torch) happen inside ``run``, in the worker process.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any

from dcseg.config import DEFAULT_SCALE
from worker.contract import input_layout
from worker.execute import Stage, StageContext, StageOutcome


def _write_json(path: Path, data: Any) -> None:
    path.write_text(json.dumps(data, indent=2, sort_keys=True, default=str), encoding="utf-8")


def capture_options(config: dict[str, Any]) -> Any:
    """``dcseg.config.CaptureOptions`` from a job's stored options (JSON lists become tuples)."""
    from dcseg.config import CaptureOptions
    from dcseg.errors import InputError, Problem

    raw = config.get("options", {}).get("capture", {})
    values: dict[str, Any] = {k: tuple(v) if isinstance(v, list) else v for k, v in raw.items()}
    try:
        return CaptureOptions(**values)
    except (TypeError, ValueError) as error:
        raise InputError([Problem("options.capture", str(error))]) from None


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
        report = validate_inputs(paths, capture_options(ctx.config))
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
            "capture_sha256": config.get("inputs", {}).get("capture"),
            "upload": config.get("inputs", {}).get("upload"),
        }

    def run(self, ctx: StageContext, out: Path) -> StageOutcome:
        try:
            from dcseg import reconstruct
        except ImportError as error:
            return StageOutcome("skipped", f"reconstruct: not available ({error})")
        if not hasattr(reconstruct, "fit_gaussians"):
            return StageOutcome("skipped", "reconstruct: dcseg.reconstruct has no fit_gaussians")
        from dcseg.io.captures import read_capture
        from dcseg.io.ply import write_gaussians_ply

        cfg = reconstruct_config(ctx.config)
        capture = read_capture(ctx.input_root, capture_options(ctx.config))

        def on_progress(iteration: int, total: int, loss: float) -> None:
            message = f"reconstruct: step {iteration}/{total}, loss {loss:.4f}"
            ctx.progress(iteration / max(total, 1), message)

        result = reconstruct.fit_gaussians(
            capture, cfg, device=resolve_device(ctx.settings.device), on_progress=on_progress
        )
        write_gaussians_ply(out / "scene.ply", result.gaussians)
        metrics = {
            "gaussians": len(result.gaussians),
            "initial_gaussians": result.initial_count,
            "extent_m": result.extent,
            "psnr": _finite(result.metrics.psnr),
            "depth_mae_m": _finite(result.metrics.depth_mae),
            "train_frames": list(result.train_frames),
            "test_frames": list(result.test_frames),
            "final_loss": result.losses[-1] if result.losses else None,
            "seconds": result.seconds,
            "config": dataclasses.asdict(cfg),
        }
        _write_json(out / "metrics.json", metrics)
        return StageOutcome("done", f"reconstruct: {len(result.gaussians)} Gaussians")


def _finite(value: float) -> float | None:
    return value if math.isfinite(value) else None


def reconstruct_config(config: dict[str, Any]) -> Any:
    """The preset named by the job, with its overrides; InputError naming a bad field."""
    from dcseg.reconstruct import PRESETS

    return _overridden(PRESETS, config, "reconstruct", "reconstruction")


def affinity_config(config: dict[str, Any]) -> Any:
    """The job's affinity-training config: its preset with ``options.affinity`` overrides."""
    from dcseg.affinity.config import PRESETS

    return _overridden(PRESETS, config, "affinity", "affinity-training")


def _overridden(presets: dict[str, Any], config: dict[str, Any], key: str, what: str) -> Any:
    from dcseg.errors import InputError, Problem

    preset = str(config.get("preset", "fast"))
    if preset not in presets:
        known = ", ".join(sorted(presets))
        raise InputError([Problem("preset", f"unknown preset {preset!r} (known: {known})")])
    overrides = dict(config.get("options", {}).get(key, {}))
    fields = {f.name for f in dataclasses.fields(presets[preset])}
    unknown = sorted(set(overrides) - fields)
    if unknown:
        reason = f"not a {what} parameter"
        raise InputError([Problem(f"options.{key}.{name}", reason) for name in unknown])
    try:
        return dataclasses.replace(presets[preset], **overrides)
    except (TypeError, ValueError) as error:
        raise InputError([Problem(f"options.{key}", str(error))]) from None


def resolve_device(device: str) -> str:
    """``auto`` = CUDA when available; imported here so CUDA starts in the worker process only."""
    if device != "auto":
        return device
    import torch

    return "cuda" if torch.cuda.is_available() else "cpu"


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
        try:
            inputs = RunInputs.from_bundle(
                ctx.input_root, scene=scene, capture_options=capture_options(ctx.config)
            )
        except InputError as error:  # a capture-only upload: reconstruct, nothing more
            return StageOutcome("skipped", f"train: {error.problems[0].reason}")
        progress = _weighted_progress(ctx, TRAIN_WEIGHTS)
        record = train_job(inputs, pipeline_config(ctx.config), out, progress)
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
        options = ctx.config.get("options", {}).get("segment", {})
        record = resegment_job(
            trained,
            out,
            scale=float(options.get("scale", DEFAULT_SCALE)),
            matcher=str(options.get("matcher", "assignment")),
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


def pipeline_config(config: dict[str, Any]) -> Any:
    """The job's ``dcseg.config.PipelineConfig``: its preset, seed, scale and matcher."""
    from dcseg.config import preset

    options = config.get("options", {}).get("segment", {})
    base = preset(str(config.get("preset", "fast")))
    cfg = dataclasses.replace(
        base, reconstruct=reconstruct_config(config), affinity=affinity_config(config)
    )
    cfg = cfg.seeded(int(options.get("seed", 0)))
    assign = dataclasses.replace(cfg.assign, mode=options.get("matcher", "assignment"))
    return dataclasses.replace(cfg, scale=float(options.get("scale", DEFAULT_SCALE)), assign=assign)


def default_stages() -> list[Stage]:
    """The stages, in order."""
    return [ValidateStage(), ReconstructStage(), TrainStage(), SegmentStage()]
