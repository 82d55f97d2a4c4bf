"""Reconstruction of an RGB-only capture (COLMAP without depth): sparse points, photometric loss.

A capture with ``depth_source == "none"`` has all-0 depth, so everything that reads depth is
switched off explicitly rather than left to find no valid pixel: the Gaussians start at the
capture's sparse points (positions, colours; sizes from nearest-neighbour distances, as 3DGS
does), the loss is colour only (L1 + SSIM), densification runs as usual, and the report says
which steps are off (:data:`dcseg.depthless.DEPTH_OFF`). After the reconstruction,
:func:`with_rendered_depth` gives the later stages (mask 3D scales, the projection metrics'
depth test) the surface depth rendered from the Gaussians in place of the missing depth.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray

from dcseg.depthless import DEPTH_OFF, RENDERED_DEPTH, SCALE_NOTE
from dcseg.gaussians import Gaussians
from dcseg.reconstruct import exposure as colour
from dcseg.reconstruct.config import ReconstructConfig
from dcseg.reconstruct.init import gaussians_from_points
from dcseg.reconstruct.sensor import exposure
from dcseg.types import Capture, Frame, SparsePoints

__all__ = [
    "PHOTOMETRIC_ONLY",
    "photometric_only",
    "rgb_only_init",
    "rgb_only_report",
    "sparse_colour_changes",
    "sparse_extent",
    "with_rendered_depth",
]

log = logging.getLogger(__name__)


PHOTOMETRIC_ONLY: dict[str, Any] = {
    "depth_weight": 0.0,
    "depth_filter_window": 1,
    "drop_flying_pixels": False,
    "init_thickness": None,
    "thickness_weight": 0.0,
    "centre_weight": 0.0,
    "opacity_weight": 0.0,
    "planar_depth": False,
}
"""The reconstruction options an RGB-only capture overrides (reported as ``overrides``)."""


def photometric_only(cfg: ReconstructConfig) -> ReconstructConfig:
    """``cfg`` with every depth-dependent step off (depth loss, depth filters, surface priors)."""
    return replace(cfg, **PHOTOMETRIC_ONLY)


def sparse_extent(frames: Sequence[Frame], sparse: SparsePoints) -> float:
    """:func:`~dcseg.reconstruct.init.scene_extent` with the sparse points as the surface:
    ``1.1 x`` the larger of the cameras' spread and the 95th percentile distance of the points
    from the cameras' mean (in the model's units)."""
    centres = np.stack([f.c2w[:3, 3] for f in frames])
    centre = centres.mean(axis=0)
    camera_radius = float(np.linalg.norm(centres - centre, axis=1).max())
    surface = float(np.percentile(np.linalg.norm(sparse.xyz - centre, axis=1), 95))
    return 1.1 * max(camera_radius, surface, 1e-3)


def rgb_only_init(
    capture: Capture,
    train: Sequence[Frame],
    cfg: ReconstructConfig,
    device: torch.device | str,
) -> tuple[ReconstructConfig, float, Gaussians]:
    """The photometric config, the scene extent and the Gaussians at the sparse points.

    At most ``cfg.max_init_points`` points are kept (a seeded random subset), each a Gaussian
    as wide as its mean distance to its 3 nearest neighbours.

    Raises:
        ValueError: the capture has no sparse points.
    """
    sparse = capture.sparse
    if sparse is None or not len(sparse):
        raise ValueError("an RGB-only capture needs sparse points to initialise the Gaussians")
    keep = np.arange(len(sparse))
    if len(keep) > cfg.max_init_points:
        rng = np.random.default_rng(cfg.seed)
        keep = np.sort(rng.choice(len(keep), cfg.max_init_points, replace=False))
    colours = sparse.rgb[keep].astype(np.float64) / 255.0
    extent = sparse_extent(train, sparse)
    init = gaussians_from_points(sparse.xyz[keep], colours, cfg, device)
    log.info(
        "RGB-only capture: %d Gaussians from %d sparse points; depth-dependent steps off (%s)",
        len(init), len(sparse), "; ".join(DEPTH_OFF),
    )  # fmt: skip
    log.info("RGB-only capture: %s", SCALE_NOTE)
    return photometric_only(cfg), extent, init


def rgb_only_report(capture: Capture, train: Sequence[Frame]) -> dict[str, Any]:
    """The ``sensor`` report of an RGB-only capture: no depth measurements, what is off, and
    the frames' exposure (colour only)."""
    sparse = capture.sparse
    return {
        "frames_measured": len(train),
        "depth": {
            "present": False,
            "sparse_points": None if sparse is None else len(sparse),
            "off": list(DEPTH_OFF),
            "overrides": dict(PHOTOMETRIC_ONLY),
            "instead": RENDERED_DEPTH,
            "scale": SCALE_NOTE,
        },
        "exposure": exposure(train) if train else None,
        "poses": None,
    }


def sparse_colour_changes(frames: Sequence[Frame], sparse: SparsePoints | None) -> dict[str, Any]:
    """Exposure changes between consecutive ``frames`` of an RGB-only capture, measured through
    its sparse points (no depth to match pixels): each frame's per-channel median
    ``log(observed / point colour)`` over the points it sees (projected in front of it, inside
    it, neither value clipped; occluded points are outvoted by the median), and the change of
    that between consecutive frames, reported as
    :func:`dcseg.reconstruct.exposure.colour_changes` reports it.

    Example:
        >>> from dcseg.types import Intrinsics
        >>> k = Intrinsics(100.0, 100.0, 15.5, 15.5, 32, 32)
        >>> xy = np.stack(np.meshgrid(np.linspace(-0.1, 0.1, 12), np.linspace(-0.1, 0.1, 12)))
        >>> xyz = np.concatenate([xy.reshape(2, -1).T, np.ones((144, 1))], 1)
        >>> points = SparsePoints(xyz, np.full((144, 3), 100, np.uint8), np.zeros(144),
        ...                       np.full(144, 2))
        >>> frames = [Frame(str(g), np.full((32, 32, 3), g, np.uint8), np.zeros((32, 32),
        ...           np.float32), k, np.eye(4)) for g in (100, 100, 120)]
        >>> round(sparse_colour_changes(frames, points)["largest_change"], 3)
        0.2
    """
    gains = [_frame_gain(f, sparse) for f in frames] if sparse is not None else []
    logs = [
        b - a for a, b in zip(gains[:-1], gains[1:], strict=True) if a is not None and b is not None
    ]
    summary = colour.changes_summary(logs)
    return {**summary, "measured_by": "sparse points"} if logs else summary


def _frame_gain(frame: Frame, sparse: SparsePoints) -> NDArray[np.float64] | None:
    """``[3]`` median per-channel log of the frame's colour over the sparse points' colour at
    the points it sees; None with fewer than ``exposure.MIN_PIXELS`` of them."""
    w2c = np.linalg.inv(frame.c2w)
    local = sparse.xyz @ w2c[:3, :3].T + w2c[:3, 3]
    ahead = local[:, 2] > 1e-6
    k, z = frame.intrinsics, np.maximum(local[:, 2], 1e-6)
    x = np.rint(local[:, 0] / z * k.fx + k.cx).astype(np.int64)
    y = np.rint(local[:, 1] / z * k.fy + k.cy).astype(np.int64)
    inside = ahead & (x >= 0) & (x < frame.width) & (y >= 0) & (y < frame.height)
    seen = np.asarray(frame.rgb, dtype=np.float64)[y[inside], x[inside]]
    ref = np.asarray(sparse.rgb, dtype=np.float64)[inside]
    low, high = colour.LIMITS
    keep = ((seen > low) & (seen < high) & (ref > low) & (ref < high)).all(axis=1)
    if int(keep.sum()) < colour.MIN_PIXELS:
        return None
    gain: NDArray[np.float64] = np.median(np.log(seen[keep] / ref[keep]), axis=0)
    return gain


def with_rendered_depth(capture: Capture, gaussians: Gaussians) -> Capture:
    """``capture`` with each frame's depth the surface depth rendered from ``gaussians``
    (``depth_source == "rendered"``); a capture with depth is returned as it is."""
    if capture.has_depth:
        return capture
    from dcseg.render import Camera
    from dcseg.render.surface_depth import surface_depth

    frames = []
    for frame in capture.frames:
        depth = surface_depth(gaussians, Camera.from_frame(frame))
        array = np.ascontiguousarray(depth.detach().cpu().numpy(), dtype=np.float32)
        files = {**frame.files, "depth": "rendered from the reconstruction"}
        frames.append(replace(frame, depth=array, files=files))
    log.info("RGB-only capture: depth of %d frames rendered from the Gaussians", len(frames))
    return replace(capture, frames=tuple(frames), depth_source="rendered")
