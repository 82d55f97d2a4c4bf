"""Stage 1 as one call, used by ``dcseg reconstruct``, ``dcseg run`` and the worker's stage.

:func:`reconstruct_scene` fits Gaussians to a capture in memory and describes the result;
:func:`reconstruct_job` reads the capture and writes ``scene.ply`` plus the report.
"""

from __future__ import annotations

import json
import math
import platform
import resource
import time
from collections.abc import Callable
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import numpy
import torch

from dcseg import __version__
from dcseg.config import NATIVE_BUDGET, CaptureOptions, FrameBudget
from dcseg.devices import resolve_device
from dcseg.errors import InputError
from dcseg.gaussians import Gaussians
from dcseg.reconstruct.config import ReconstructConfig
from dcseg.reconstruct.poses import refinement_report
from dcseg.reconstruct.stage import Reconstruction
from dcseg.sizes import SceneSize, SizeRules, reconstruct_record
from dcseg.types import Capture

StepProgress = Callable[[int, int, float], None]
"""``on_progress(step, total, loss)``."""


def device_of(name: str) -> torch.device:
    """:func:`resolve_device`, as an InputError naming ``device``."""
    try:
        return resolve_device(name)
    except ValueError as error:
        raise InputError.single("device", str(error)) from None


def reconstruct_scene(
    capture: Capture,
    cfg: ReconstructConfig,
    device: torch.device,
    on_progress: StepProgress | None = None,
) -> tuple[Gaussians, dict[str, Any]]:
    """Fit Gaussians on ``device``; returns them and their report (metrics, frames, config)."""
    from dcseg.reconstruct import fit_gaussians
    from dcseg.render import select_backend

    try:
        backend = select_backend(device, cfg.backend)
    except ValueError as error:
        raise InputError.single("backend", str(error)) from None
    result = fit_gaussians(
        capture, replace(cfg, backend=backend), device=device, on_progress=on_progress
    )
    return result.gaussians, _report(result, cfg, backend, device)


def reconstruct_job(
    capture_path: Path,
    options: CaptureOptions,
    cfg: ReconstructConfig,
    out: Path,
    *,
    budget: FrameBudget = NATIVE_BUDGET,
    device: str = "auto",
    on_progress: StepProgress | None = None,
    report_name: str = "reconstruction.json",
    rules: SizeRules | None = None,
) -> dict[str, Any]:
    """Read a capture, reconstruct it and write ``out/scene.ply`` and ``out/<report_name>``.

    With pose refinement the refined poses go to ``out/poses.json``; without, a ``poses.json``
    left there by an earlier reconstruction is removed (it belongs to that scene).

    Only the frames ``budget`` selects are read, at its working resolution
    (:mod:`dcseg.io.captures.plan`); the report's ``capture`` records that choice. With
    ``rules``, ``cfg`` holds the values at the reference size and the size rules
    (:mod:`dcseg.sizes`) set them for the planned views and pixels; the report's
    ``size_rules`` lists the values and ``config`` is what ran. None = ``cfg`` as given.

    Returns:
        The report, with read/write timings, the peak memory and the library versions.
    """
    from dcseg.io.captures import read_planned
    from dcseg.io.ply import write_gaussians_ply
    from dcseg.io.poses import POSES_FILE, write_poses

    where = device_of(device)
    start = time.perf_counter()
    capture, plan = read_planned(capture_path, options, budget)
    read_s = time.perf_counter() - start
    size = SceneSize(views=len(capture), pixels=plan.size[0] * plan.size[1])
    cfg, rules_record = reconstruct_record(cfg, rules or SizeRules(enabled=False), size)
    gaussians, report = reconstruct_scene(capture, cfg, where, on_progress)
    report["capture"] = plan.summary()
    report["size_rules"] = rules_record
    start = time.perf_counter()
    out.mkdir(parents=True, exist_ok=True)
    write_gaussians_ply(out / "scene.ply", gaussians)
    refinement = report.get("pose_refinement")
    if refinement is not None:  # the poses go to their own file, beside the scene
        write_poses(out / POSES_FILE, refinement.pop("poses"))
        refinement["file"] = POSES_FILE
    else:  # an earlier refined scene's poses would be read with this scene
        (out / POSES_FILE).unlink(missing_ok=True)
    seconds = {"read": read_s, **report["seconds"], "write": time.perf_counter() - start}
    report["seconds"] = {key: round(value, 3) for key, value in seconds.items()}
    report["peak_memory_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    report["versions"] = _versions()
    (out / report_name).write_text(json.dumps(report, indent=2) + "\n", encoding="utf-8")
    return report


def _finite(value: float) -> float | None:
    return value if math.isfinite(value) else None


def _report(
    result: Reconstruction, cfg: ReconstructConfig, backend: str, device: torch.device
) -> dict[str, Any]:
    metrics = result.metrics
    return {
        "psnr": _finite(metrics.psnr),
        "depth_mae": _finite(metrics.depth_mae),
        "surface_depth_mae": _finite(metrics.surface_depth_mae),
        "views": [
            {
                "name": v.name,
                "psnr": _finite(v.psnr),
                "depth_mae": _finite(v.depth_mae),
                "surface_depth_mae": _finite(v.surface_depth_mae),
                "depth_pixels": v.depth_pixels,
            }
            for v in metrics.views
        ],
        "gaussians": len(result.gaussians),
        "initial_gaussians": result.initial_count,
        "depth_noise_at_1m": result.depth_noise,
        "extent": result.extent,
        "train_frames": list(result.train_frames),
        "test_frames": list(result.test_frames),
        "final_loss": result.losses[-1] if result.losses else None,
        "seconds": dict(result.seconds),
        "backend": backend,
        "device": str(device),
        "seed": cfg.seed,
        "config": asdict(cfg),
        "pose_refinement": _refinement(result),
    }


def _refinement(result: Reconstruction) -> dict[str, Any] | None:
    if result.poses is None or result.original_poses is None:
        return None
    return refinement_report(result.original_poses, result.poses)


def _versions() -> dict[str, str]:
    return {
        "dcseg": __version__,
        "python": platform.python_version(),
        "torch": torch.__version__,
        "numpy": numpy.__version__,
    }
