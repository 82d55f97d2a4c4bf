"""The stage entry point: initialise from depth, optimise, evaluate held-out frames."""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray

from dcseg.gaussians import Gaussians
from dcseg.io.poses import CameraFile
from dcseg.reconstruct import calibration, exposure, pose_check, registration
from dcseg.reconstruct.align import align_pose
from dcseg.reconstruct.config import ReconstructConfig
from dcseg.reconstruct.depth_filter import DepthFilter
from dcseg.reconstruct.evaluate import Metrics, evaluate
from dcseg.reconstruct.fit import FitResult, ProgressCallback, optimise
from dcseg.reconstruct.init import init_from_frames, scene_extent
from dcseg.reconstruct.observed import observed
from dcseg.reconstruct.poses import change_stats, corrected_c2w
from dcseg.reconstruct.rgbonly import rgb_only_init, rgb_only_report, sparse_colour_changes
from dcseg.reconstruct.sensor import log_report, sensor_report
from dcseg.reconstruct.sharpness import blur_decision, log_decision
from dcseg.reconstruct.views import make_view, split_frames
from dcseg.types import Capture, Frame

log = logging.getLogger(__name__)

_Cameras = tuple[registration.Registration, calibration.Correction | None]
"""The registration and the intrinsics correction a reconstruction applied."""


@dataclass(frozen=True)
class Reconstruction:
    """The result of :func:`fit_gaussians`.

    Attributes:
        gaussians: the optimised Gaussians (detached, on the training device).
        metrics: held-out metrics (empty when nothing is held out).
        extent: the scene radius (metres) used for learning rates and density control.
        train_frames: names of the frames trained on.
        test_frames: names of the held-out frames.
        losses: the training loss of every step.
        seconds: wall time per phase (``init``, ``train``, ``eval``).
        initial_count: number of Gaussians after initialisation.
        depth_noise: the training views' measured depth noise at 1 m (metres; it grows with
            the squared depth, :mod:`dcseg.reconstruct.depth_noise`); 0.0 for noise-free
            depth, None when no window of the depth could be measured.
        poses: per frame name (trained and held out) its refined camera-to-world pose, None
            when poses are not refined (``cfg.pose_lr`` = 0).
        original_poses: the poses refinement started from (None likewise): the capture's, or
            its colour cameras' where the registration found a baseline.
        sensor: what was detected in the training frames and applied
            (:func:`dcseg.reconstruct.sensor.sensor_report`).
        cameras: the cameras fitted where they differ from the capture's (the depth
            registered onto the colour by another colour camera, corrected intrinsics,
            refined poses): every frame's pose and the records ``poses.json`` keeps; None
            when the capture's cameras were used as they are.
        applied: the configuration the optimisation ran with: the requested one as the
            detections (pose refinement off: ``pose_lr`` 0) and an RGB-only capture (depth
            steps off) changed it; None when not recorded.
    """

    gaussians: Gaussians
    metrics: Metrics
    extent: float
    train_frames: tuple[str, ...]
    test_frames: tuple[str, ...]
    losses: tuple[float, ...]
    seconds: dict[str, float]
    initial_count: int
    depth_noise: float | None = None
    poses: dict[str, NDArray[np.float64]] | None = None
    original_poses: dict[str, NDArray[np.float64]] | None = None
    sensor: dict[str, Any] = field(default_factory=dict)
    applied: ReconstructConfig | None = None
    cameras: CameraFile | None = None


def fit_gaussians(
    capture: Capture,
    cfg: ReconstructConfig,
    *,
    device: torch.device | str = "cpu",
    on_progress: ProgressCallback | None = None,
) -> Reconstruction:
    """Reconstruct Gaussians from a posed RGB-D capture.

    Every ``cfg.holdout``-th frame (indices 0, k, 2k, ...) is held out; the others initialise
    the Gaussians from depth and are trained on, one random view per step, at
    ``1 / cfg.train_downscale`` resolution. Held-out frames are evaluated at full resolution.

    Args:
        capture: the posed RGB-D frames.
        cfg: the reconstruction parameters (see :data:`PRESETS`).
        device: where the optimisation runs (all tensors follow it).
        on_progress: called as ``on_progress(iteration, total, loss)`` after every step.

    Returns:
        The Gaussians, held-out metrics, timings and the loss curve.
    """
    torch.manual_seed(cfg.seed)
    train, test = split_frames(capture.frames, cfg.holdout)
    seconds: dict[str, float] = {}
    start = time.perf_counter()
    camera_entries: dict[str, Any] = {}
    cameras = None
    if capture.has_depth:
        train, test, camera_entries, cameras = _cameras(capture, train, test, cfg)
    seconds["registration"] = time.perf_counter() - start
    start = time.perf_counter()
    if capture.has_depth:
        extent = scene_extent(train)
        init = init_from_frames(train, cfg, extent=extent, device=device)
    else:  # RGB-only: sparse points, photometric loss only (rgbonly.py)
        cfg, extent, init = rgb_only_init(capture, train, cfg, device)
    denoise = DepthFilter.of(cfg)
    views = [make_view(f, cfg.train_downscale, device, denoise) for f in train]
    fine = None
    if cfg.full_res_from is not None and cfg.train_downscale > 1:
        fine = [make_view(f, 1, device, denoise) for f in train]
    seconds["init"] = time.perf_counter() - start
    log.info("init: %d Gaussians, extent %.3f m, %d training views", len(init), extent, len(views))
    start = time.perf_counter()
    if capture.has_depth:
        sensor = sensor_report(train, cfg.drop_flying_pixels, cfg.depth_filter_window)
        log_report(sensor)
        colour_on = _detect_exposure(exposure.colour_changes(train), cfg, sensor)
        cfg = _detect_misalignment(cfg, sensor)
    else:  # RGB-only: colour matched through the sparse points; the pose check needs depth
        sensor = rgb_only_report(capture, train)
        colour_on = _detect_exposure(sparse_colour_changes(train, capture.sparse), cfg, sensor)
        cfg = cfg if cfg.pose_refinement == "on" else replace(cfg, pose_lr=0.0)
    sensor.update(camera_entries)
    blur = blur_decision(train, cfg.blurred_frames)
    sensor["motion_blur"] = blur.report([f.name for f in train])
    log_decision(blur)
    seconds["sensor"] = time.perf_counter() - start
    noise = sensor["depth"]["noise"]["a_at_1m"] if sensor and capture.has_depth else None

    start = time.perf_counter()
    fitted = optimise(
        init, views, cfg, extent, fine_views=fine, on_progress=on_progress, exposure=colour_on,
        colour_weights=tuple(blur.weights),
    )  # fmt: skip
    seconds["train"] = time.perf_counter() - start
    if fitted.colour is not None and sensor:
        summary = exposure.gains_summary(fitted.colour, [f.name for f in train])
        sensor["exposure"]["fitted"] = summary
        exposure.log_fitted(summary)

    poses = None
    started = {f.name: f.c2w for f in (*train, *test)}  # at the colour camera, if registered
    if fitted.corrections is not None:
        start = time.perf_counter()
        poses = refined_poses(fitted, train, test, cfg, device)
        test = tuple(replace(f, c2w=poses[f.name]) for f in test)
        seconds["align"] = time.perf_counter() - start
        _log_change(started, poses)
    start = time.perf_counter()
    held_out = [make_view(f, 1, device) for f in test]
    colours = _held_out_exposure(fitted, capture, train, test)
    seen = _observed(capture, train, test, poses)
    metrics = evaluate(
        fitted.gaussians, held_out, cfg.backend, planar=cfg.planar_depth, colours=colours,
        observed=seen,
    )  # fmt: skip
    seconds["eval"] = time.perf_counter() - start
    log.info("held-out %s", held_out_line(metrics))
    return Reconstruction(
        gaussians=fitted.gaussians,
        metrics=metrics,
        extent=extent,
        train_frames=tuple(f.name for f in train),
        test_frames=tuple(f.name for f in test),
        losses=fitted.losses,
        seconds=seconds,
        initial_count=len(init),
        depth_noise=noise,
        poses=poses,
        original_poses=None if poses is None else started,
        sensor=sensor,
        applied=cfg,
        cameras=_camera_file(cameras, train, test, poses),
    )


def _observed(
    capture: Capture,
    train: Sequence[Frame],
    test: Sequence[Frame],
    poses: Mapping[str, NDArray[np.float64]] | None,
) -> list[torch.Tensor] | None:
    """Per held-out frame the pixels the training frames (at their refined poses) observed
    (:func:`dcseg.reconstruct.observed.observed`); None for an RGB-only capture."""
    if not capture.has_depth:
        return None
    if poses is not None:
        train = tuple(replace(f, c2w=poses.get(f.name, f.c2w)) for f in train)
    return [torch.from_numpy(observed(f, train)) for f in test]


def _held_out_exposure(
    fitted: FitResult, capture: Capture, train: Sequence[Frame], test: Sequence[Frame]
) -> torch.Tensor | None:
    """Every held-out frame's exposure predicted from the trained frames around it in capture
    order (:func:`exposure.interpolated`); None when no exposure was fitted."""
    if fitted.colour is None or not test:
        return None
    order = {f.name: i for i, f in enumerate(capture.frames)}
    trained = [order[f.name] for f in train]
    return exposure.interpolated(trained, fitted.colour, [order[f.name] for f in test])


def _detect_exposure(
    measured: dict[str, Any], cfg: ReconstructConfig, sensor: dict[str, Any]
) -> bool:
    """Whether a colour transform per view is fitted (:func:`exposure.decide`) on the
    ``measured`` changes (:func:`exposure.colour_changes` or, RGB-only,
    :func:`sparse_colour_changes`); the detection goes into ``sensor["exposure"]`` and the log."""
    on = exposure.decide(cfg.exposure, measured)
    if sensor:
        report = exposure.detection_report(measured, cfg.exposure, on)
        sensor["exposure"].update(report)
        exposure.log_detection(report)
    return on


def _cameras(
    capture: Capture, train: Sequence[Frame], test: Sequence[Frame], cfg: ReconstructConfig
) -> tuple[tuple[Frame, ...], tuple[Frame, ...], dict[str, Any], _Cameras]:
    """The frames with their depth moved onto the colour (:func:`_register`), then their
    intrinsics corrected (:func:`_calibrate`); the ``sensor`` entries and what was applied."""
    train, test, entry, reg = _register(train, test, cfg)
    train, test, intrinsics, fix = _calibrate(capture, train, test, cfg)
    return train, test, {"registration": entry, "intrinsics": intrinsics}, (reg, fix)


def _register(
    train: Sequence[Frame], test: Sequence[Frame], cfg: ReconstructConfig
) -> tuple[tuple[Frame, ...], tuple[Frame, ...], dict[str, Any], registration.Registration]:
    """The frames with their depth moved onto the colour by the given or estimated
    registration (:mod:`dcseg.reconstruct.registration`), the ``sensor.registration`` entry
    (logged) and the registration."""
    given = (cfg.depth_shift_x, cfg.depth_shift_y)
    auto = given == (0, 0) and cfg.depth_registration == "auto"
    measured = registration.estimate(train) if auto else None
    reg = registration.decide(cfg.depth_registration, given, measured)
    entry = registration.report(cfg.depth_registration, given, measured, reg)
    registration.log_decision(entry)
    return registration.registered(train, reg), registration.registered(test, reg), entry, reg


def _calibrate(
    capture: Capture, train: Sequence[Frame], test: Sequence[Frame], cfg: ReconstructConfig
) -> tuple[tuple[Frame, ...], tuple[Frame, ...], dict[str, Any], calibration.Correction | None]:
    """The frames with their intrinsics corrected where ``auto`` finds them clearly wrong
    (:mod:`dcseg.reconstruct.calibration`), the ``sensor.intrinsics`` entry (logged) and the
    correction; a capture with a calibrated lens keeps its intrinsics."""
    mode, why_not = cfg.intrinsics_refinement, None
    if mode == "auto" and any(f.undistortion is not None for f in capture.frames):
        why_not = "the capture's lens is calibrated (distortion given)"
    measured = calibration.estimate(train) if mode == "auto" and why_not is None else None
    fix = calibration.decide(mode, measured)
    entry = calibration.report(mode, measured, fix, why_not)
    if train:
        calibration.log_decision(entry, train[0].intrinsics)
    return calibration.corrected(train, fix), calibration.corrected(test, fix), entry, fix


def _camera_file(
    cameras: _Cameras | None,
    train: Sequence[Frame],
    test: Sequence[Frame],
    poses: dict[str, NDArray[np.float64]] | None,
) -> CameraFile | None:
    """What ``poses.json`` keeps: every frame's pose (refined, or moved to its colour camera)
    and the applied records; None when the frames are the capture's."""
    reg, fix = cameras if cameras is not None else (registration.Registration(), None)
    if poses is None and reg.identity and fix is None:
        return None
    final = poses if poses is not None else {f.name: f.c2w for f in (*train, *test)}
    return CameraFile(
        dict(final),
        None if reg.identity else reg.record(),
        None if fix is None else fix.record(),
    )


def _detect_misalignment(cfg: ReconstructConfig, sensor: dict[str, Any]) -> ReconstructConfig:
    """``cfg`` with ``pose_lr`` 0 unless poses are refined (:func:`pose_check.decide`); the
    decision goes into ``sensor["poses"]`` and the log."""
    agreement = sensor.get("poses")
    on = pose_check.decide(cfg.pose_refinement, agreement) and cfg.pose_lr > 0
    report = pose_check.detection_report(agreement, cfg.pose_refinement, on)
    sensor["poses"] = {**(agreement or {}), **report}
    pose_check.log_detection(agreement, report)
    return cfg if on else replace(cfg, pose_lr=0.0)


def held_out_line(metrics: Metrics) -> str:
    """The held-out scores for the log; a score that was not measured (no fitted exposure,
    no held-out depth: NaN) is named as such rather than printed as ``nan``."""
    parts = [f"PSNR {metrics.psnr:.2f} dB", f"colour-compensated {metrics.compensated_psnr:.2f} dB"]
    if math.isfinite(metrics.neighbour_psnr):
        parts.append(f"under the neighbours' exposure {metrics.neighbour_psnr:.2f} dB")
    if math.isfinite(metrics.observed_share) and metrics.observed_share < 1.0:
        parts.append(
            f"over the {100 * metrics.observed_share:.1f} % of pixels training views saw "
            f"{metrics.observed_psnr:.2f} dB"
        )
    if math.isfinite(metrics.depth_mae):
        parts.append(
            f"depth MAE {metrics.depth_mae:.4f} m (surface depth {metrics.surface_depth_mae:.4f} m)"
        )
    else:
        parts.append("no depth MAE (no held-out depth)")
    return ", ".join(parts)


def _log_change(
    before: dict[str, NDArray[np.float64]], after: dict[str, NDArray[np.float64]]
) -> None:
    stats = change_stats(before, after)
    rot, move = stats["rotation_deg"], stats["translation_m"]
    log.info(
        "refined poses: median change %.2f deg, %.1f mm (largest %.2f deg, %.1f mm)",
        rot["median"], move["median"] * 1000, rot["max"], move["max"] * 1000,
    )  # fmt: skip


def refined_poses(
    fitted: FitResult,
    train: Sequence[Frame],
    test: Sequence[Frame],
    cfg: ReconstructConfig,
    device: torch.device | str,
) -> dict[str, NDArray[np.float64]]:
    """Every frame's refined pose: the trained frames' fitted corrections, and each held-out
    frame aligned to the fitted Gaussians at the training resolution (:func:`align_pose`)."""
    assert fitted.corrections is not None
    out = {
        f.name: corrected_c2w(f.c2w, delta)
        for f, delta in zip(train, fitted.corrections, strict=True)
    }
    for frame in test:
        view = make_view(frame, cfg.train_downscale, device)
        out[frame.name] = corrected_c2w(frame.c2w, align_pose(fitted.gaussians, view, cfg))
    return out
