"""Motion-blurred training frames: detected from their colour, down-weighted or skipped.

A camera turning fast while its shutter is open smears the image along the motion; training
the Gaussians' colour on such a frame blurs the scene for every view. How sharp a frame looks
also depends on what it shows (a textured shelf against a bare wall), and that changes along
the trajectory, so no absolute threshold separates blurred from sharp frames. A frame is
judged against its temporal neighbours instead:

* :func:`sharpness`: the energy of the Laplacian of the frame's luma at a fixed working
  width (:data:`WORK_WIDTH`, area averaged: sensor noise and the capture's resolution matter
  less); blur takes the fine detail away;
* :func:`blur_scores`: each frame's sharpness over the median of its :data:`NEIGHBOURS`
  previous and next training frames' (1 = as sharp as its neighbours);
* :func:`blur_decision`: frames scoring below :data:`BLURRED` are blurred. ``weight`` scales
  their colour loss by their score, ``skip`` drops their colour loss (weight 0) when sharp
  neighbours see what they see (:func:`covered`), else weights it; their depth is trained
  either way (a depth sensor's exposure is short). Sharp frames keep weight 1, so a sharp
  capture trains exactly as without the check.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from dcseg.reconstruct.init import backproject_points, project_points
from dcseg.types import Frame

log = logging.getLogger(__name__)

MODES = ("weight", "skip", "off")
"""What :func:`blur_decision` does with blurred frames (``ReconstructConfig.blurred_frames``)."""

WORK_WIDTH = 160
"""Width (pixels, about) at which sharpness is measured: frames are area-averaged by the
integer factor that brings them closest to it."""

NEIGHBOURS = 4
"""A frame is compared with the median sharpness of this many training frames on each side."""

BLURRED = 0.4
"""Frames below this share of their neighbours' sharpness are blurred. On 40-view 320x240
synthetic orbits (neighbouring views 9 degrees apart, far more than a handheld capture's
consecutive frames) sharp views scored at least 0.58, views with 12 px blur at most 0.25."""

COVERED = 0.9
"""``skip`` drops a blurred frame's colour only when sharp neighbours see at least this share
of its depth pixels (:func:`covered`)."""

COVER_GRID = 8
"""The coverage check projects every this-many-th pixel along both axes."""


def luma(rgb: NDArray[np.uint8]) -> NDArray[np.float32]:
    """``[h, w]`` luma in [0, 1] of ``rgb`` area-averaged to about :data:`WORK_WIDTH`.

    OpenCV's Rec. 601 grey (rounded to 8 bits at full resolution, an error the averaging
    shrinks) then a float area average: 1.7 ms for a 640x480 frame where the same in numpy
    took 7-12 ms."""
    factor = max(1, round(rgb.shape[1] / WORK_WIDTH))
    h, w = rgb.shape[0] // factor, rgb.shape[1] // factor
    grey = cv2.cvtColor(np.ascontiguousarray(rgb[: h * factor, : w * factor]), cv2.COLOR_RGB2GRAY)
    small = cv2.resize(grey.astype(np.float32), (w, h), interpolation=cv2.INTER_AREA)
    out: NDArray[np.float32] = small / np.float32(255.0)
    return out


def sharpness(rgb: NDArray[np.uint8]) -> float:
    """Mean squared 4-neighbour Laplacian of the working-resolution luma (:func:`luma`).

    On 40-view 320x240 synthetic orbits (``dcseg synth``, seeds 0-2, 12 px blur on a quarter
    of the views) it separated blurred from sharp frames better than the smallest of four
    directional gradient energies or the plain gradient energy (table in
    ``benchmarks/README.md``, "Motion blur")."""
    y = luma(rgb)
    lap = 4.0 * y[1:-1, 1:-1] - y[:-2, 1:-1] - y[2:, 1:-1] - y[1:-1, :-2] - y[1:-1, 2:]
    return float(np.square(lap).mean())


def blur_scores(
    values: Sequence[float], neighbours: int = NEIGHBOURS, passes: int = 3
) -> NDArray[np.float64]:
    """Each of ``values`` (sharpness in capture order) over the median of its ``2 *
    neighbours`` nearest others (the window shifts inwards at the ends of the sequence)
    judged sharp: each pass drops the frames the previous one scored below :data:`BLURRED`
    from the references, so a run of blurred frames does not lower its own reference.
    1.0 for a single frame or where no reference has texture."""
    v = np.asarray(values, dtype=np.float64)
    n = len(v)
    sharp = np.ones(n, dtype=bool)
    scores = np.ones(n)
    for _ in range(passes):
        for i in range(n):
            ref = _reference(v, sharp, i, neighbours)
            scores[i] = v[i] / ref if ref > 0 else 1.0
        sharp = scores >= BLURRED
    return scores


def _reference(v: NDArray[np.float64], sharp: NDArray[np.bool_], i: int, half: int) -> float:
    """Median of ``v`` over the ``2 * half`` frames nearest ``i`` (``i`` excluded) that are
    ``sharp``, widening the window until it holds some (0.0 when none is)."""
    n = len(v)
    width = 2 * half
    while True:
        lo = min(max(0, i - width // 2), max(0, n - 1 - width))
        hi = min(n, lo + width + 1)
        idx = [j for j in range(lo, hi) if j != i and sharp[j]]
        if len(idx) >= half or width >= n:
            return float(np.median(v[idx])) if idx else 0.0
        width *= 2


@dataclass(frozen=True)
class BlurDecision:
    """What :func:`blur_decision` found and applied.

    Attributes:
        mode: one of :data:`MODES`.
        scores: per training frame its sharpness over its neighbours' (:func:`blur_scores`).
        blurred: per training frame whether it scores below :data:`BLURRED`.
        weights: per training frame the weight of its colour loss (1 for sharp frames).
        coverage: per blurred frame (by index) the share of its depth pixels that sharp
            neighbours see (``skip`` only).
        seconds: time the measurement took.
    """

    mode: str
    scores: NDArray[np.float64]
    blurred: NDArray[np.bool_]
    weights: NDArray[np.float64]
    coverage: dict[int, float]
    seconds: float

    def report(self, names: Sequence[str]) -> dict[str, Any]:
        """The ``sensor.motion_blur`` entry of ``reconstruction.json``."""
        q = np.percentile(self.scores, [0, 5, 25, 50]) if len(self.scores) else np.zeros(4)
        frames = [
            {
                "name": names[i],
                "score": round(float(self.scores[i]), 4),
                "colour_weight": round(float(self.weights[i]), 4),
                **({"coverage": round(self.coverage[i], 4)} if i in self.coverage else {}),
            }
            for i in map(int, np.flatnonzero(self.blurred))
        ]
        return {
            "mode": self.mode,
            "threshold": BLURRED,
            "frames_checked": len(self.scores),
            "blurred": len(frames),
            "skipped": int((self.weights[self.blurred] == 0).sum()),
            "score_quantiles": {
                k: round(float(x), 4)
                for k, x in zip(("min", "p5", "p25", "median"), q, strict=True)
            },
            "frames": frames,
            "seconds": round(self.seconds, 3),
        }


def blur_decision(frames: Sequence[Frame], mode: str) -> BlurDecision:
    """Score ``frames`` (the training frames, in capture order) and choose their colour
    weights by ``mode`` (module docstring); ``off`` scores them and keeps every weight 1."""
    if mode not in MODES:
        raise ValueError(f"blurred_frames must be one of {MODES}, got {mode!r}")
    start = time.perf_counter()
    scores = blur_scores([sharpness(f.rgb) for f in frames])
    blurred = scores < BLURRED
    weights = np.ones(len(frames))
    coverage: dict[int, float] = {}
    if mode != "off":
        weights[blurred] = scores[blurred]
    if mode == "skip":
        for i in np.flatnonzero(blurred):
            coverage[int(i)] = covered(frames, int(i), blurred)
            if coverage[int(i)] >= COVERED:
                weights[i] = 0.0
    return BlurDecision(mode, scores, blurred, weights, coverage, time.perf_counter() - start)


def covered(frames: Sequence[Frame], index: int, blurred: NDArray[np.bool_]) -> float:
    """The share of frame ``index``'s depth pixels (every :data:`COVER_GRID`-th) that at
    least one sharp frame among its :data:`NEIGHBOURS` on each side sees unoccluded (1.0
    when it has no depth: nothing to lose)."""
    world, _ = backproject_points(frames[index], COVER_GRID)
    if len(world) == 0:
        return 1.0
    seen = np.zeros(len(world), dtype=bool)
    lo, hi = max(0, index - NEIGHBOURS), min(len(frames), index + NEIGHBOURS + 1)
    for j in range(lo, hi):
        if j != index and not blurred[j]:
            seen |= sees(frames[j], world)
    return float(seen.mean())


def sees(frame: Frame, world: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Which ``world`` points ``frame`` sees: in front, inside the image, and within 10 % of
    its depth at the nearest pixel (farther means occluded; no depth there counts as seen)."""
    x, y, z, inside = project_points(frame, world)
    observed = np.zeros(len(z))
    observed[inside] = frame.depth[y[inside], x[inside]]
    unoccluded = (observed <= 0) | (z < 1.1 * observed)
    out: NDArray[np.bool_] = inside & unoccluded
    return out


def log_decision(decision: BlurDecision) -> None:
    """One log line: how many frames are blurred and what was done with them."""
    n, blurred = len(decision.scores), int(decision.blurred.sum())
    done = {
        "weight": "their colour loss weighted by their score",
        "skip": f"{int((decision.weights == 0).sum())} skipped for colour, the rest weighted",
        "off": "not handled (blurred_frames off)",
    }[decision.mode]
    if blurred == 0:
        done = "all trained as they are"
    lowest = float(decision.scores.min()) if n else 1.0
    log.info(
        "motion blur: %d of %d training frames blurred (below %.0f %% of their neighbours' "
        "sharpness; lowest %.0f %%), %s, %.2f s",
        blurred, n, 100 * BLURRED, 100 * lowest, done, decision.seconds,
    )  # fmt: skip
