"""A trivial depth baseline for held-out views: the nearest training frames' own depth.

Each training frame's depth points (at its refined pose) are projected into the held-out
frame, the nearest point per pixel kept; the nearest training frame in capture order fills a
pixel first, the next the pixels it left empty. No fit, no fusion: what the sensor itself
says a few frames away. Where this beats the fitted Gaussians' render, the data held depth
that the fit lost (``held_out_errors`` reports both on the same pixels).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from dcseg.reconstruct.init import backproject_points, project_points
from dcseg.types import Frame

NEIGHBOURS = 2
"""Training frames warped into each held-out frame (the nearest in capture order)."""

AGREE = 0.03
"""Metres within which the warped depth counts as agreeing with the held-out depth."""

GAPS = (1, 2, 4, 8)
"""One training frame this many training frames away from each held-out frame (the earlier
side when there is one) is also warped alone: how fast the sensor's own depth stops agreeing
with the held-out depth as the viewpoint moves away."""

CORE = 0.1
"""Errors below this (metres) are the core, above it the tail (occlusions, missing things)."""


def nearest(frame: Frame, train: Sequence[Frame], order: Mapping[str, int]) -> list[Frame]:
    """The :data:`NEIGHBOURS` frames of ``train`` nearest ``frame`` in capture ``order``."""
    at = order[frame.name]
    return sorted(train, key=lambda f: (abs(order[f.name] - at), order[f.name]))[:NEIGHBOURS]


def at_gap(
    frame: Frame, train: Sequence[Frame], order: Mapping[str, int], gap: int
) -> Frame | None:
    """The training frame ``gap`` places before ``frame`` among ``train`` in capture ``order``
    (after it when there is none before; None when neither exists)."""
    ranked = sorted(train, key=lambda f: order[f.name])
    place = sum(order[f.name] < order[frame.name] for f in ranked)
    if place - gap >= 0:
        return ranked[place - gap]
    after = place + gap - 1
    return ranked[after] if after < len(ranked) else None


def projected(frame: Frame, source: Frame) -> NDArray[np.float32]:
    """``[H, W]`` depth in ``frame`` of ``source``'s depth points (nearest per pixel, 0 = none)."""
    world, _ = backproject_points(source)
    u, v, z, inside = project_points(frame, world)
    u, v, z = u[inside], v[inside], z[inside]
    far_first = np.argsort(-z)
    out = np.zeros((frame.height, frame.width), dtype=np.float32)
    out[v[far_first], u[far_first]] = z[far_first]
    return out


def warped(frame: Frame, sources: Sequence[Frame]) -> NDArray[np.float32]:
    """``frame``'s depth as ``sources`` saw it: the first source's where it has any, then the
    next's."""
    out = np.zeros((frame.height, frame.width), dtype=np.float32)
    for source in sources:
        depth = projected(frame, source)
        out = np.where(out > 0, out, depth)
    return out


def compared(
    rendered: NDArray[np.float32], truth: NDArray[np.float32], neighbour: NDArray[np.float32]
) -> dict[str, float]:
    """Sums over the pixels with both held-out and warped depth: the render's and the warp's
    absolute errors, the render's tail (> 0.1 m) and the part of it the warp got within
    :data:`AGREE`; ``valid`` counts the held-out pixels with depth."""
    both = (truth > 0) & (neighbour > 0)
    render_error = np.abs(rendered - truth)[both]
    warp_error = np.abs(neighbour - truth)[both]
    tail = render_error > 0.1
    return {
        "pixels": float(both.sum()),
        "valid": float((truth > 0).sum()),
        "render_abs": float(render_error.sum()),
        "warp_abs": float(warp_error.sum()),
        "render_tail": float(tail.sum()),
        "tail_warp_agrees": float((tail & (warp_error < AGREE)).sum()),
    }


def by_gap(
    rendered: NDArray[np.float32], truth: NDArray[np.float32], warp: NDArray[np.float32]
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """The warp's and the render's signed errors on the pixels both have with the held-out
    depth (for medians and core means pooled over views)."""
    both = (truth > 0) & (warp > 0)
    return (warp - truth)[both], (rendered - truth)[both]


def gap_summary(warp: NDArray[np.float32], render: NDArray[np.float32]) -> dict[str, float]:
    """MAE, median and the core's MAE (errors below :data:`CORE`) of the pooled signed errors
    of one gap's warp and of the render on the same pixels, in millimetres."""
    out: dict[str, float] = {"pixels": float(warp.size)}
    for name, error in (("warp", np.abs(warp)), ("render", np.abs(render))):
        core = error[error < CORE]
        out[f"{name}_mae_mm"] = 1e3 * float(error.mean())
        out[f"{name}_median_mm"] = 1e3 * float(np.median(error))
        out[f"{name}_core_mae_mm"] = 1e3 * float(core.mean()) if core.size else float("nan")
        out[f"{name}_tail_share"] = float((error >= CORE).mean())
    return out
