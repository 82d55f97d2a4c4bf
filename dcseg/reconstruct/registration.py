"""Colour/depth misregistration: a pixel shift between depth edges and colour edges.

Sensors with separate depth and colour cameras (Kinect, RealSense, phones) register depth to
colour with a calibration; when it is off, every depth map sits a few pixels beside its
colour image, and the Gaussians initialised and trained on it put the colour of one surface
on the depth of its neighbour (halos at object boundaries, fattened foreground). Depth
discontinuities are almost always colour edges too (an object's silhouette against what is
behind it), so the shift that best lays the depth edges onto strong colour gradients is the
misregistration:

* :func:`edge_scores`: on up to :data:`MAX_FRAMES` frames, the mean colour gradient magnitude
  (:func:`gradient`, over the frame's mean) at the depth-edge pixels moved by every shift
  within :data:`RADIUS` pixels;
* :func:`estimate`: the best shift and how much it gains over none; ``auto`` moves the depth
  by it when it is non-zero and gains more than :data:`MIN_GAIN` (texture beside depth edges
  also draws the best shift, so only clear gains are trusted);
* a shift given in the configuration (``ReconstructConfig.depth_shift_x``/``_y``) is applied
  as it is, without estimation.

A single image shift models a calibration's rotation error (or its translation at one depth);
the parallax of a wrong baseline changes with depth and is only approximated.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from dcseg.types import Frame

log = logging.getLogger(__name__)

MODES = ("auto", "off")
"""``ReconstructConfig.depth_registration``: estimate the shift (applied when clear), or not."""

RADIUS = 6
"""Shifts up to this many pixels along each axis are tried."""

MAX_FRAMES = 12
"""The estimate uses at most this many frames, evenly spread."""

EDGE_JUMP = 0.05
"""A pixel is a depth edge when its neighbours on either side (horizontal or vertical) differ
in depth by more than this fraction of the nearer one."""

MIN_GAIN = 0.25
"""``auto`` applies a non-zero shift only when its edge score beats no shift's by more than
this fraction (25 %). Measured (benchmarks/README "Real-sensor detection"): registered
synthetic scenes and Replica room0 0 (best shift none); synthetic 3 px shifts about 1.0;
but texture beside depth edges can pull the best shift off a registered scene: the analytic
test scene (stripes 2 px below a box's top edge) 0.12-0.21 at 32x24-64x48. Smaller gains
are reported, not applied (the slambook2 Kinect sample: 2 px, see the README)."""

EDGES_PER_FRAME = 4000
"""At most this many depth-edge pixels per frame are scored (evenly strided in raster order):
the 169 shifts cost a gather each, and a 1200x680 frame has ~7000 edge pixels."""

MIN_EDGE_PIXELS = 1000
"""``auto`` applies no shift measured on fewer depth-edge pixels."""


def shifted(image: NDArray[Any], shift: tuple[int, int]) -> NDArray[Any]:
    """``image`` moved ``shift = (dx, dy)`` pixels (right, down), 0 where nothing moved in."""
    dx, dy = shift
    if dx == 0 and dy == 0:
        return image
    out = np.zeros_like(image)
    h, w = image.shape[:2]
    if abs(dx) >= w or abs(dy) >= h:
        return out
    out[max(dy, 0) : h + min(dy, 0), max(dx, 0) : w + min(dx, 0)] = image[
        max(-dy, 0) : h - max(dy, 0), max(-dx, 0) : w - max(dx, 0)
    ]
    return out


def depth_edges(depth: NDArray[np.float32]) -> NDArray[np.bool_]:
    """``[h, w]`` the pixels whose two horizontal or two vertical neighbours (both with depth)
    differ by more than :data:`EDGE_JUMP` of the nearer."""
    d = np.asarray(depth, dtype=np.float32)
    out = np.zeros(d.shape, dtype=bool)
    for a, b, inner in (
        (d[:, :-2], d[:, 2:], (slice(None), slice(1, -1))),
        (d[:-2, :], d[2:, :], (slice(1, -1), slice(None))),
    ):
        near = np.minimum(a, b)
        out[inner] |= (near > 0) & (np.abs(a - b) > EDGE_JUMP * near)
    return out


def gradient(rgb: NDArray[np.uint8]) -> NDArray[np.float32]:
    """``[h, w]`` the largest Sobel gradient magnitude of the three colour channels, over its
    mean (1 = an average pixel). Per channel, not of the luma: a red box on a blue floor of
    the same brightness still has an edge (on the analytic test scene the luma's weak
    silhouettes let the box's stripes 2 px away win, gain 0.28 instead of 0.21; a 3 px
    synthetic shift gains 1.07 instead of 0.80)."""
    magnitude = np.zeros(rgb.shape[:2], dtype=np.float32)
    for c in range(3):
        channel = np.ascontiguousarray(rgb[..., c]).astype(np.float32)
        gx = cv2.Sobel(channel, cv2.CV_32F, 1, 0, ksize=3)
        gy = cv2.Sobel(channel, cv2.CV_32F, 0, 1, ksize=3)
        np.maximum(magnitude, np.sqrt(gx * gx + gy * gy), out=magnitude)
    mean = float(magnitude.mean())
    return magnitude / np.float32(mean) if mean > 0 else magnitude


def edge_scores(frames: Sequence[Frame], radius: int = RADIUS) -> tuple[NDArray[np.float64], int]:
    """``([2r+1, 2r+1], edge pixels)``: at ``[dy + r, dx + r]`` the mean colour gradient
    (:func:`gradient`) at the depth edges moved by ``(dx, dy)``, over ``frames``; the edges
    within ``radius`` of the border are left out so that every shift sees the same ones."""
    r = radius
    sums = np.zeros((2 * r + 1, 2 * r + 1))
    count = 0
    for frame in frames:
        if frame.depth.shape != frame.rgb.shape[:2]:
            continue
        edges = depth_edges(frame.depth)
        edges[:r], edges[-r:], edges[:, :r], edges[:, -r:] = False, False, False, False
        ys, xs = np.nonzero(edges)
        if len(ys) == 0:
            continue
        stride = -(-len(ys) // EDGES_PER_FRAME)  # ceil: at most EDGES_PER_FRAME
        ys, xs = ys[::stride], xs[::stride]
        g = gradient(frame.rgb)
        for dy in range(-r, r + 1):
            for dx in range(-r, r + 1):
                sums[dy + r, dx + r] += float(g[ys + dy, xs + dx].sum())
        count += len(ys)
    return (sums / count if count else sums), count


def estimate(frames: Sequence[Frame]) -> dict[str, Any]:
    """The shift ``(dx, dy)`` that moves the depth edges of ``frames`` onto the colour edges
    (colour edge = depth edge + shift), its score and gain over no shift, and the depth-edge
    pixels measured; shift None without depth edges."""
    sample = _spread(frames, MAX_FRAMES)
    scores, count = edge_scores(sample)
    if count == 0:
        return {"shift_px": None, "gain": None, "edge_pixels": 0, "frames": len(sample)}
    r = (scores.shape[0] - 1) // 2
    dy, dx = np.unravel_index(int(np.argmax(scores)), scores.shape)
    zero = float(scores[r, r])
    best = float(scores[dy, dx])
    return {
        "shift_px": [int(dx) - r, int(dy) - r],
        "score": round(best, 4),
        "score_unshifted": round(zero, 4),
        "gain": round(best / zero - 1.0, 4) if zero > 0 else None,
        "edge_pixels": count,
        "frames": len(sample),
    }


def _spread(frames: Sequence[Frame], most: int) -> list[Frame]:
    if len(frames) <= most:
        return list(frames)
    return [frames[int(i)] for i in np.linspace(0, len(frames) - 1, most).round()]


def decide(mode: str, given: tuple[int, int], measured: dict[str, Any] | None) -> tuple[int, int]:
    """The shift (colour edge = depth edge + shift) the depth is moved by: ``given`` when
    non-zero, else in ``auto`` the measured one when non-zero, it gains more than
    :data:`MIN_GAIN` and was measured on at least :data:`MIN_EDGE_PIXELS`, else none."""
    if given != (0, 0):
        return given
    if mode != "auto" or measured is None or measured.get("shift_px") is None:
        return (0, 0)
    gain = measured.get("gain")
    if gain is None or gain <= MIN_GAIN or measured.get("edge_pixels", 0) < MIN_EDGE_PIXELS:
        return (0, 0)
    dx, dy = measured["shift_px"]
    return (int(dx), int(dy))


def registered(frames: Sequence[Frame], shift: tuple[int, int]) -> tuple[Frame, ...]:
    """``frames`` with their depth moved by ``shift`` onto the colour (unchanged at 0)."""
    if shift == (0, 0):
        return tuple(frames)
    return tuple(replace(f, depth=shifted(f.depth, shift)) for f in frames)


def report(
    mode: str, given: tuple[int, int], measured: dict[str, Any] | None, applied: tuple[int, int]
) -> dict[str, Any]:
    """The ``sensor.registration`` entry of ``reconstruction.json``."""
    return {
        "mode": "given" if given != (0, 0) else mode,
        "measured": measured,
        "min_gain": MIN_GAIN,
        "min_edge_pixels": MIN_EDGE_PIXELS,
        "applied_shift_px": list(applied),
    }


def log_decision(entry: dict[str, Any]) -> None:
    """One log line: the measured shift, its gain, and what was applied."""
    measured, applied = entry["measured"], entry["applied_shift_px"]
    done = f"depth moved by {applied} px onto the colour" if any(applied) else "depth as is"
    if entry["mode"] == "given":
        log.info("colour/depth registration: given shift %s px: %s", applied, done)
    elif measured is None:
        log.info("colour/depth registration: not estimated (%s): %s", entry["mode"], done)
    elif measured["shift_px"] is None:
        log.info("colour/depth registration: no depth edges to measure: %s", done)
    else:
        log.info(
            "colour/depth registration: colour edges sit %s px from the depth edges "
            "(edge contrast +%.1f %% over none, %d edge pixels): %s",
            measured["shift_px"],
            100 * (measured["gain"] or 0.0),
            measured["edge_pixels"],
            done,
        )
