"""What a capture's sensor did, detected from its frames, and what the reconstruction applied.

:func:`sensor_report` measures, on the training frames (at most :data:`MAX_FRAMES` of them,
evenly spread, for the per-pixel measurements):

* ``depth``: the quantisation step (and the depth scale it implies) and the noise model
  ``sigma(z) = a z^2`` (:mod:`dcseg.reconstruct.depth_noise`), the share of pixels without
  depth, and the flying pixels at depth edges (:mod:`dcseg.reconstruct.flying`) with whether
  they were dropped;
* ``exposure``: every frame's mean brightness (Rec. 601 luma of its colour): the spread over
  frames and the largest change between consecutive frames, which a changing exposure or white
  balance shows as much as a changing view (the reconstruction adds what
  :mod:`dcseg.reconstruct.exposure` measures at corresponding pixels and fits);
* ``poses``: how well consecutive frames' depth agrees once one is projected into the other
  with the capture's poses, next to what the measured noise alone explains: a ratio well above
  1 points at pose misalignment (:mod:`dcseg.reconstruct.pose_check` decides from it
  whether poses are refined).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dcseg.reconstruct.depth_noise import noise_model
from dcseg.reconstruct.flying import flying_share
from dcseg.types import Frame

log = logging.getLogger(__name__)

MAX_FRAMES = 60
"""Per-pixel measurements (noise, flying pixels, depth agreement) use at most this many frames."""

AGREEMENT_GRID = 8
"""Depth agreement projects every this-many-th pixel of both axes and interpolates the other
frame's depth bilinearly (the nearest pixel alone would add half a pixel's depth slope)."""

OCCLUSION = 0.1
"""Projected depths off by more than this fraction are occlusions, not misalignment."""

LUMA = np.array([0.299, 0.587, 0.114])
"""Rec. 601 luma weights of R, G, B."""


def sensor_report(
    frames: Sequence[Frame], drop_flying: bool, median_window: int = 1
) -> dict[str, Any]:
    """The detected effects of ``frames`` (module docstring); ``drop_flying``,
    ``median_window``: whether the reconstruction drops flying pixels and the depth filter's
    window (1 = off), as configured. Whether poses are refined is decided from ``poses``
    (:mod:`dcseg.reconstruct.pose_check`)."""
    if not frames:
        return {}
    sample = _spread(frames, MAX_FRAMES)
    depth = depth_effects(sample, drop_flying)
    a = depth["noise"]["a_at_1m"] or 0.0
    # the filter runs on the views whose own measured noise is above 0
    depth["median_filter"] = {"window": median_window, "applied": median_window > 1 and a > 0}
    return {
        "frames_measured": len(sample),
        "depth": depth,
        "exposure": exposure(frames),
        "poses": depth_agreement(sample, a, depth["noise"]["quantisation_step"]),
    }


def _spread(frames: Sequence[Frame], most: int) -> list[Frame]:
    if len(frames) <= most:
        return list(frames)
    return [frames[int(i)] for i in np.linspace(0, len(frames) - 1, most).round()]


def depth_effects(frames: Sequence[Frame], drop_flying: bool) -> dict[str, Any]:
    """Noise model, missing depth and flying pixels of ``frames``."""
    model = noise_model([f.depth for f in frames])
    a = model.a or 0.0
    pixels = sum(f.depth.size for f in frames)
    missing = sum(int((f.depth <= 0).sum()) for f in frames)
    counts = [flying_share(f.depth, a, model.step) for f in frames]
    flying, edges = sum(c[0] for c in counts), sum(c[1] for c in counts)
    valid = pixels - missing
    return {
        "noise": model.as_dict(),
        "missing_fraction": missing / pixels if pixels else None,
        "flying_pixels": {
            "share_of_edge_pixels": flying / edges if edges else 0.0,
            "share_of_valid_pixels": flying / valid if valid else 0.0,
            "edge_pixels": edges,
            "dropped": drop_flying,
        },
    }


def exposure(frames: Sequence[Frame]) -> dict[str, Any]:
    """Per-frame mean brightness in [0, 1]: mean, spread (sd / mean), range, and the largest
    ratio between consecutive frames."""
    means = np.array([_brightness(f.rgb) for f in frames])
    mean = float(means.mean())
    steps = [0.0]
    if len(means) > 1:
        low = np.maximum(np.minimum(means[1:], means[:-1]), 1e-6)
        steps = list(np.maximum(means[1:], means[:-1]) / low - 1.0)
    return {
        "mean_brightness": mean,
        "spread": float(means.std() / mean) if mean > 0 else 0.0,
        "min": float(means.min()),
        "max": float(means.max()),
        "largest_consecutive_change": float(max(steps)),
    }


def _brightness(rgb: NDArray[np.uint8]) -> float:
    sub = np.asarray(rgb[::4, ::4], dtype=np.float64)
    return float((sub @ LUMA).mean() / 255.0)


def depth_agreement(frames: Sequence[Frame], a: float, step: float) -> dict[str, Any] | None:
    """Median over consecutive pairs of ``frames`` of the median absolute difference between
    one frame's depth projected into the other and the other's depth (occlusions excluded),
    the same expected from the noise alone (``sqrt(2) a z^2`` plus a step), and their ratio;
    and the median of each pair's :func:`tilt` (degrees): the relative rotation about the image
    axes that the disagreement's systematic part implies, which noise averages away. None with
    fewer than two frames or no overlap."""
    measured, expected, tilts = [], [], []
    for first, second in zip(frames[:-1], frames[1:], strict=True):
        pair = pair_disagreement(first, second)
        if pair is None:
            continue
        diff, z, xn, yn = pair
        measured.append(float(np.median(np.abs(diff))))
        expected.append(float(np.median(np.sqrt(2.0) * a * z * z)) + step)
        tilts.append(tilt(diff, z, xn, yn))
    if not measured:
        return None
    m, e = float(np.median(measured)), float(np.median(expected))
    return {
        "depth_disagreement": m,
        "expected_from_noise": e,
        "ratio": m / e if e > 0 else None,
        "tilt_deg": float(np.median(tilts)),
        "pairs": len(measured),
    }


def tilt(
    diff: NDArray[np.float64], z: NDArray[np.float64], xn: NDArray[np.float64],
    yn: NDArray[np.float64],
) -> float:  # fmt: skip
    """Degrees of relative rotation about the camera's x and y axes that best explain the
    depth differences ``diff`` at depths ``z`` and normalised image coordinates ``(xn, yn)``:
    to first order a rotation ``w`` and translation ``t`` change a point's depth by
    ``z (w_x yn - w_y xn) + t_z``, fitted by least squares after dropping differences more
    than 3 median deviations from the median (edges). Exact poses give ~0 at any noise.

    Example:
        >>> xn, yn = np.meshgrid(np.linspace(-0.5, 0.5, 20), np.linspace(-0.4, 0.4, 20))
        >>> xn, yn, z = xn.ravel(), yn.ravel(), np.full(400, 2.0)
        >>> round(tilt(z * np.radians(0.3) * yn + 0.01, z, xn, yn), 3)
        0.3
    """
    spread = np.median(np.abs(diff - np.median(diff))) + 1e-9
    keep = np.abs(diff - np.median(diff)) <= 3.0 * spread
    design = np.stack([np.ones(int(keep.sum())), z[keep] * yn[keep], -z[keep] * xn[keep]], 1)
    coef, *_ = np.linalg.lstsq(design, diff[keep], rcond=None)
    return float(np.degrees(np.hypot(coef[1], coef[2])))


def pair_disagreement(src: Frame, dst: Frame) -> tuple[NDArray[np.float64], ...] | None:
    """``(projected - observed depth, observed depth, x / z, y / z)`` of ``src``'s grid pixels
    seen by ``dst`` with valid depth (``dst``'s camera coordinates), occlusions dropped; None
    when they see nothing in common."""
    g = AGREEMENT_GRID
    depth = np.asarray(src.depth[::g, ::g], dtype=np.float64)
    rows, cols = np.nonzero(depth > 0)
    z = depth[rows, cols]
    k = src.intrinsics
    u, v = cols * g, rows * g
    cam = np.stack([(u - k.cx) / k.fx * z, (v - k.cy) / k.fy * z, z], axis=1)
    world = cam @ src.c2w[:3, :3].T + src.c2w[:3, 3]
    w2c = np.linalg.inv(dst.c2w)
    local = world @ w2c[:3, :3].T + w2c[:3, 3]
    ahead = local[:, 2] > 1e-6
    local = local[ahead]
    kd = dst.intrinsics
    xn, yn = local[:, 0] / local[:, 2], local[:, 1] / local[:, 2]
    x, y = xn * kd.fx + kd.cx, yn * kd.fy + kd.cy
    inside = (x >= 0) & (x < dst.width - 1) & (y >= 0) & (y < dst.height - 1)
    x, y, zp = x[inside], y[inside], local[inside, 2]
    observed = _bilinear(np.asarray(dst.depth, dtype=np.float64), x, y)
    keep = (observed > 0) & (np.abs(zp - observed) < OCCLUSION * observed)
    if int(keep.sum()) < 10:
        return None
    return zp[keep] - observed[keep], observed[keep], xn[inside][keep], yn[inside][keep]


def _bilinear(
    depth: NDArray[np.float64], x: NDArray[np.float64], y: NDArray[np.float64]
) -> NDArray[np.float64]:
    """``depth`` interpolated at ``(x, y)`` (inside the image, one pixel from its right and
    bottom edges); 0 where any of the four pixels is invalid or they span a depth edge."""
    x0, y0 = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
    fx, fy = x - x0, y - y0
    corners = np.stack(
        [depth[y0, x0], depth[y0, x0 + 1], depth[y0 + 1, x0], depth[y0 + 1, x0 + 1]], axis=1
    )
    weights = np.stack([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy], axis=1)
    value = (corners * weights).sum(axis=1)
    low, high = corners.min(axis=1), corners.max(axis=1)
    smooth = (low > 0) & (high - low < OCCLUSION * low)
    out: NDArray[np.float64] = np.where(smooth, value, 0.0)
    return out


def quantisation_line(noise: dict[str, Any]) -> str:
    """How the depth is quantised, for the log: in disparity (steps ``c z^2``), in depth, or
    neither."""
    c = noise.get("disparity_step") or 0.0
    if c > 0:
        return f"in disparity (steps {c * 1000:.1f} mm at 1 m, {c * 6250:.1f} mm at 2.5 m)"
    step = noise["quantisation_step"]
    return f"step {step * 1000:.3f} mm" if step > 0 else "none (continuous depth)"


def log_report(report: dict[str, Any]) -> None:
    """One log line per detected effect of :func:`sensor_report`."""
    if not report:
        return
    depth = report["depth"]
    noise, flying = depth["noise"], depth["flying_pixels"]
    a = noise["a_at_1m"]
    log.info(
        "depth: quantisation %s, noise at 1 m %s (sigma = a z^2), %.1f %% missing",
        quantisation_line(noise),
        "unmeasured" if a is None else f"{a * 1000:.2f} mm",
        100 * (depth["missing_fraction"] or 0.0),
    )
    log.info(
        "depth edges: %.1f %% flying pixels (%.2f %% of valid depth), %s; noise %s",
        100 * flying["share_of_edge_pixels"],
        100 * flying["share_of_valid_pixels"],
        "dropped" if flying["dropped"] else "kept",
        "median-filtered" if depth["median_filter"]["applied"] else "not filtered",
    )
    ex = report["exposure"]
    log.info(
        "brightness: spread %.1f %% over frames, largest change between frames %.1f %%",
        100 * ex["spread"],
        100 * ex["largest_consecutive_change"],
    )
    poses = report["poses"]
    if poses is not None:
        log.info(
            "pose check: consecutive frames' depth disagrees by %.1f mm (median), %.1f mm "
            "expected from the noise",
            poses["depth_disagreement"] * 1000,
            poses["expected_from_noise"] * 1000,
        )
