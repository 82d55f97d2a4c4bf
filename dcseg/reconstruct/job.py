"""Stage 1 as one call: :func:`reconstruct_scene` fits Gaussians to a capture in memory and
describes the result (the reconstruct stage, :mod:`dcseg.stages.reconstruct`, reads the capture
and writes the files)."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, replace
from typing import Any

import torch

from dcseg.devices import resolve_device
from dcseg.errors import InputError
from dcseg.gaussians import Gaussians
from dcseg.io.poses import CameraFile
from dcseg.lens import of_frames, records
from dcseg.reconstruct.config import ReconstructConfig
from dcseg.reconstruct.poses import refinement_report
from dcseg.reconstruct.stage import Reconstruction
from dcseg.types import Capture

StepProgress = Callable[[int, int, float], None]
"""``on_progress(step, total, loss)``: what the optimisation loops call
(:func:`dcseg.progress.steps` turns a :data:`~dcseg.progress.Progress` into one)."""


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
) -> tuple[Gaussians, dict[str, Any], CameraFile | None]:
    """Fit Gaussians on ``device``; returns them, their report (metrics, frames, config) and
    the cameras they were fitted to where these differ from the capture's (``poses.json``)."""
    from dcseg.reconstruct import fit_gaussians
    from dcseg.render import select_backend

    try:
        backend = select_backend(device, cfg.backend)
    except ValueError as error:
        raise InputError.single("backend", str(error)) from None
    result = fit_gaussians(
        capture, replace(cfg, backend=backend), device=device, on_progress=on_progress
    )
    report = _report(result, cfg, backend, device)
    report["undistortion"] = records(of_frames(capture.frames))
    return result.gaussians, report, result.cameras


def _finite(value: float) -> float | None:
    return value if math.isfinite(value) else None


def _report(
    result: Reconstruction, cfg: ReconstructConfig, backend: str, device: torch.device
) -> dict[str, Any]:
    metrics = result.metrics
    return {
        "psnr": _finite(metrics.psnr),
        "psnr_colour_compensated": _finite(metrics.compensated_psnr),
        "psnr_neighbour_exposure": _finite(metrics.neighbour_psnr),
        "psnr_observed": _finite(metrics.observed_psnr),
        "observed_share": _finite(metrics.observed_share),
        "depth_mae": _finite(metrics.depth_mae),
        "surface_depth_mae": _finite(metrics.surface_depth_mae),
        "views": [
            {
                "name": v.name,
                "psnr": _finite(v.psnr),
                "psnr_colour_compensated": _finite(v.compensated_psnr),
                "psnr_neighbour_exposure": _finite(v.neighbour_psnr),
                "psnr_observed": _finite(v.observed_psnr),
                "observed_share": _finite(v.observed_share),
                "depth_mae": _finite(v.depth_mae),
                "surface_depth_mae": _finite(v.surface_depth_mae),
                "depth_pixels": v.depth_pixels,
            }
            for v in metrics.views
        ],
        "gaussians": len(result.gaussians),
        "initial_gaussians": result.initial_count,
        "depth_noise_at_1m": result.depth_noise,
        "sensor": result.sensor,
        "extent": result.extent,
        "train_frames": list(result.train_frames),
        "test_frames": list(result.test_frames),
        "final_loss": result.losses[-1] if result.losses else None,
        "seconds": dict(result.seconds),
        "backend": backend,
        "device": str(device),
        "seed": cfg.seed,
        "config": asdict(cfg),
        "config_changes": config_changes(cfg, result.applied),
        "pose_refinement": _refinement(result),
    }


def config_changes(
    requested: ReconstructConfig, applied: ReconstructConfig | None
) -> dict[str, dict[str, Any]]:
    """The fields the run changed from the requested configuration (the detections, an
    RGB-only capture), each as ``{"requested": ..., "applied": ...}``; the backend resolved
    from ``auto`` is reported as ``backend``, not here.

    Example:
        >>> cfg = ReconstructConfig()
        >>> config_changes(cfg, replace(cfg, pose_lr=0.0))
        {'pose_lr': {'requested': 0.001, 'applied': 0.0}}
    """
    if applied is None:
        return {}
    wanted, ran = asdict(replace(requested, backend=applied.backend)), asdict(applied)
    return {k: {"requested": wanted[k], "applied": ran[k]} for k in wanted if wanted[k] != ran[k]}


def _refinement(result: Reconstruction) -> dict[str, Any] | None:
    if result.poses is None or result.original_poses is None:
        return None
    return refinement_report(result.original_poses, result.poses)
