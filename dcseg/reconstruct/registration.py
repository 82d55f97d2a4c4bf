"""Colour/depth misregistration: where each depth pixel lies in the colour image.

Sensors with separate depth and colour cameras (Kinect, RealSense, phones) register depth to
colour with a calibration; when it is off, every depth map sits a few pixels beside its
colour image, and the Gaussians initialised and trained on it put the colour of one surface
on the depth of its neighbour (halos at object boundaries, fattened foreground). Depth
discontinuities are almost always colour edges too (an object's silhouette against what is
behind it), so the shift that best lays the depth edges onto strong colour gradients is the
misregistration:

* :func:`estimate`: on up to :data:`MAX_FRAMES` frames, the mean colour gradient magnitude
  (:func:`gradient`, over the frame's mean) at the depth-edge pixels moved by a
  :class:`Registration`: every whole-pixel shift within :data:`RADIUS`, then a colour camera
  with its own focal length (:data:`SCALES`) and a baseline (:data:`PARALLAXES`), each kept only
  when it beats the simpler model by :data:`MIN_STEP_GAIN`; ``auto`` moves the depth by the
  best when it gains more than :data:`MIN_GAIN` over none (texture beside depth edges also
  draws the best shift, so only clear gains are trusted);
* a shift given in the configuration (``ReconstructConfig.depth_shift_x``/``_y``) is applied
  as it is, without estimation.

A single image shift models a calibration's rotation error (or its translation at one depth);
a colour camera of its own (raw Kinect v1 pairs) needs the scale and the baseline's parallax,
which shrinks with depth. The registered frames keep their intrinsics: which camera they
describe is settled by :mod:`dcseg.reconstruct.calibration`, run on the registered frames.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, replace
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
are reported, not applied (the slambook2 Kinect sample: 2 px, see the README); raw Kinect v1
pairs (7-Scenes) 1.0 with their colour camera's scale and parallax; heavy synthetic noise can
draw a spurious scale at 0.11-0.12 (``results/detect_intrinsics.json``)."""

EDGES_PER_FRAME = 4000
"""At most this many depth-edge pixels per frame are scored (evenly strided in raster order):
the 169 shifts cost a gather each, and a 1200x680 frame has ~7000 edge pixels."""

MIN_EDGE_PIXELS = 1000
"""``auto`` applies no shift measured on fewer depth-edge pixels."""

SCALES = np.round(np.arange(0.80, 1.12 + 1e-9, 0.02), 4)
"""Colour-over-depth focal length ratios searched (Kinect v1's uncalibrated pair: 0.9)."""

PARALLAXES = np.arange(-40.0, 40.0 + 1e-9, 2.0)
"""Parallaxes searched (pixels x metres: a 585 px focal length and a 6.8 cm baseline give 40)."""

COARSE_LEADS = 8
"""The best of the coarse scale-and-shift grid (4 px apart) refined to whole pixels: the
right scale with a shift 2 px off can score below a wrong one's."""

MIN_STEP_GAIN = 0.05
"""A scale is kept only when it raises the edge score by more than this fraction over the
whole-pixel shift alone, and a parallax over the scale without one: texture near depth edges
gives every model a little. Measured on 7-Scenes redkitchen (Kinect v1, raw pairs): the scale
raises it from 1.23 to 2.18, the parallax to 2.44 (+12 %)."""


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


@dataclass(frozen=True)
class Registration:
    """Where a depth pixel ``(u, v)`` at depth ``z`` lies in the colour image:
    ``u' = s (u - cx) + cx + dx + p / z``, ``v' = s (v - cy) + cy + dy`` (``s`` = ``scale``,
    ``(dx, dy)`` = ``shift_px``, ``p`` = ``parallax``, ``(cx, cy)`` the principal point).
    A colour camera whose focal length is ``s`` times the depth camera's, whose principal
    point is ``(dx, dy)`` away and whose centre sits ``-p / (s fx)`` metres along the depth
    camera's x axis (Kinect v1: 525 vs 585 px, 2.5 cm; the 7-Scenes captures) gives this; a
    calibrated registration that is off by a rotation gives a shift alone."""

    scale: float = 1.0
    shift_px: tuple[float, float] = (0.0, 0.0)
    parallax: float = 0.0
    size: tuple[int, int] | None = None
    """The image size (width, height) the shift and parallax are in pixels of; None = any."""

    def at(self, width: int, height: int) -> Registration:
        """This registration for images of ``width`` x ``height`` (shift and parallax scaled
        from :attr:`size`)."""
        if self.size is None or self.size == (width, height):
            return replace(self, size=None)
        sx, sy = width / self.size[0], height / self.size[1]
        shift = (self.shift_px[0] * sx, self.shift_px[1] * sy)
        return Registration(self.scale, shift, self.parallax * sx)

    @property
    def identity(self) -> bool:
        return self.scale == 1.0 and self.shift_px == (0.0, 0.0) and self.parallax == 0.0

    @property
    def integer_shift(self) -> tuple[int, int] | None:
        """The shift when the registration is a whole-pixel shift alone, else None."""
        dx, dy = self.shift_px
        plain = self.scale == 1.0 and self.parallax == 0.0
        return (int(dx), int(dy)) if plain and dx.is_integer() and dy.is_integer() else None

    def baseline_m(self, fx: float) -> float:
        """Where the colour camera's centre sits along the depth camera's x axis (metres),
        for a depth focal length ``fx``: ``-p / (s fx)``."""
        return -self.parallax / (self.scale * fx)

    def record(self) -> dict[str, Any]:
        """The JSON form (``reconstruction.json``, ``poses.json``)."""
        out: dict[str, Any] = {
            "scale": round(self.scale, 5),
            "shift_px": [round(v, 3) for v in self.shift_px],
            "parallax_px_m": round(self.parallax, 4),
        }
        if self.size is not None:
            out["at_size"] = list(self.size)
        return out

    @classmethod
    def of_record(cls, record: Any) -> Registration:
        """The registration of :meth:`record`'s output; ValueError naming the bad field."""
        if not isinstance(record, dict):
            raise ValueError("a registration must be an object")
        scale = ratio(record.get("scale"), "scale")
        shift: Any = record.get("shift_px")
        parallax: Any = record.get("parallax_px_m")
        if not (isinstance(shift, list) and len(shift) == 2):
            raise ValueError('"shift_px" must be two numbers')
        if not finite_numbers([*shift, parallax], 3):
            raise ValueError('"shift_px" and "parallax_px_m" must be finite numbers')
        size = record.get("at_size")
        at = None if size is None else image_size(size)
        return cls(scale, (float(shift[0]), float(shift[1])), float(parallax), at)


def ratio(value: Any, field: str) -> float:
    """``value`` as a scale factor of a record (a number in (0.1, 10)); ValueError naming
    ``field``."""
    if not (finite_numbers([value], 1) and 0.1 < value < 10.0):
        raise ValueError(f'"{field}" must be a number in (0.1, 10)')
    return float(value)


def finite_numbers(values: Any, count: int) -> bool:
    """Whether ``values`` is a list of ``count`` finite JSON numbers (booleans are not)."""
    return (
        isinstance(values, list)
        and len(values) == count
        and all(_number(v) and np.isfinite(v) for v in values)
    )


def image_size(value: Any) -> tuple[int, int]:
    """``value`` as a record's ``at_size`` (width, height: whole numbers of at least 1);
    ValueError naming the field."""
    if not (isinstance(value, list) and len(value) == 2 and all(_whole(v) for v in value)):
        raise ValueError('"at_size" must be a width and a height of at least 1')
    return int(value[0]), int(value[1])


def _number(value: Any) -> bool:
    """A JSON number (not a boolean)."""
    return isinstance(value, int | float) and not isinstance(value, bool)


def _whole(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 1


@dataclass(frozen=True)
class _Edges:
    """One frame's colour gradient and its depth edges (pixels and the nearer depth)."""

    gradient: NDArray[np.float32]
    x: NDArray[np.float64]
    y: NDArray[np.float64]
    z: NDArray[np.float64]
    centre: tuple[float, float]


def _edges(frame: Frame) -> _Edges | None:
    """The depth-edge pixels of ``frame`` (at most :data:`EDGES_PER_FRAME`, evenly strided)
    away from the border by :data:`RADIUS`, with the nearer depth of their 3x3 window."""
    if frame.depth.shape != frame.rgb.shape[:2]:
        return None
    r = RADIUS
    edges = depth_edges(frame.depth)
    edges[:r], edges[-r:], edges[:, :r], edges[:, -r:] = False, False, False, False
    ys, xs = np.nonzero(edges)
    if len(ys) == 0:
        return None
    stride = -(-len(ys) // EDGES_PER_FRAME)  # ceil: at most EDGES_PER_FRAME
    ys, xs = ys[::stride], xs[::stride]
    depth = np.where(frame.depth > 0, frame.depth, np.float32(1e6)).astype(np.float32)
    near = cv2.erode(depth, np.ones((3, 3), np.uint8))[ys, xs].astype(np.float64)
    k = frame.intrinsics
    return _Edges(gradient(frame.rgb), xs.astype(np.float64), ys.astype(np.float64), near,
                  (k.cx, k.cy))  # fmt: skip


def _nearest(x: NDArray[np.floating[Any]]) -> NDArray[np.int64]:
    """The nearest whole pixel, halves rounded up (``rint`` rounds them to even: a half-pixel
    shift would then send pairs of pixels to one and leave the next empty)."""
    out: NDArray[np.int64] = np.floor(x + 0.5).astype(np.int64)
    return out


def _score(edges: Sequence[_Edges], reg: Registration) -> float:
    """The mean colour gradient at the depth edges moved by ``reg`` (0 for pixels it moves
    out of the image)."""
    total, count = 0.0, 0
    s, (dx, dy), p = reg.scale, reg.shift_px, reg.parallax
    for e in edges:
        h, w = e.gradient.shape
        cx, cy = e.centre
        u = _nearest(s * (e.x - cx) + cx + dx + p / e.z)
        v = _nearest(s * (e.y - cy) + cy + dy)
        inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
        total += float(e.gradient[v[inside], u[inside]].sum())
        count += len(u)
    return total / count if count else 0.0


def _best(edges: Sequence[_Edges], candidates: Iterable[Registration]) -> Registration:
    return max(candidates, key=lambda reg: _score(edges, reg))


def _grid(reg: Registration, span: float, step: float) -> Iterator[Registration]:
    """``reg`` with every shift within ``span`` pixels of its own, ``step`` apart."""
    offsets = np.round(np.arange(-span, span + 1e-9, step), 3)
    for oy in offsets:
        for ox in offsets:
            shift = (float(reg.shift_px[0] + ox), float(reg.shift_px[1] + oy))
            yield replace(reg, shift_px=shift)


def _widened(gradient: NDArray[np.float32]) -> NDArray[np.float32]:
    """``gradient`` with each pixel the largest of its 5x5 window: edges a coarse grid's
    step (4 px) apart still score."""
    return np.asarray(cv2.dilate(gradient, np.ones((5, 5), np.uint8)), dtype=np.float32)


def _search(edges: Sequence[_Edges]) -> Registration:
    """Whole-pixel shifts within :data:`RADIUS`; then scales (:data:`SCALES`) with coarse
    shifts, the parallax with the horizontal shift, and a finer pass, each kept only when it
    scores higher."""
    best = _best(edges, _grid(Registration(), RADIUS, 1.0))
    coarse = [reg for s in SCALES for reg in _grid(Registration(float(s)), 4 * RADIUS, 4.0)]
    wide = [replace(e, gradient=_widened(e.gradient)) for e in edges]
    scores = np.array([_score(wide, reg) for reg in coarse])  # 4 px apart: widened edges
    leads = [coarse[int(i)] for i in np.argsort(-scores)[:COARSE_LEADS]]
    scaled = _best(edges, (reg for lead in leads for reg in _grid(lead, 3.0, 1.0)))
    if _score(edges, scaled) <= _score(edges, best) * (1.0 + MIN_STEP_GAIN):
        return best
    best = scaled
    near = _best(edges, (
        replace(best, parallax=float(p), shift_px=(best.shift_px[0] + float(o), best.shift_px[1]))
        for p in PARALLAXES for o in np.arange(-8.0, 8.0 + 1e-9, 1.0)
    ))  # fmt: skip
    if _score(edges, near) > _score(edges, best) * (1.0 + MIN_STEP_GAIN):
        best = near
    fine = np.round(best.scale + np.arange(-0.01, 0.01 + 1e-9, 0.0025), 4)
    return _best(edges, (
        reg for s in fine for reg in _grid(replace(best, scale=float(s)), 1.5, 0.5)
    ))  # fmt: skip


def estimate(frames: Sequence[Frame]) -> dict[str, Any]:
    """The registration that moves the depth edges of ``frames`` onto the colour edges
    (:class:`Registration`), its score and gain over none, and the depth-edge pixels
    measured; ``registration`` None without depth edges. ``shift_px`` is its shift."""
    sample = _spread(frames, MAX_FRAMES)
    edges = [e for e in (_edges(f) for f in sample) if e is not None]
    count = sum(len(e.x) for e in edges)
    if count == 0:
        return {"registration": None, "shift_px": None, "gain": None, "edge_pixels": 0,
                "frames": len(sample)}  # fmt: skip
    best = _search(edges)
    zero, score = _score(edges, Registration()), _score(edges, best)
    record = replace(best, size=(sample[0].width, sample[0].height)).record()
    return {
        "registration": record,
        "shift_px": record["shift_px"],
        "score": round(score, 4),
        "score_unshifted": round(zero, 4),
        "gain": round(score / zero - 1.0, 4) if zero > 0 else None,
        "edge_pixels": count,
        "frames": len(sample),
    }


def _spread(frames: Sequence[Frame], most: int) -> list[Frame]:
    if len(frames) <= most:
        return list(frames)
    return [frames[int(i)] for i in np.linspace(0, len(frames) - 1, most).round()]


def decide(mode: str, given: tuple[int, int], measured: dict[str, Any] | None) -> Registration:
    """The registration the depth is moved by: the ``given`` shift when non-zero, else in
    ``auto`` the measured one when it gains more than :data:`MIN_GAIN` and was measured on at
    least :data:`MIN_EDGE_PIXELS`, else none."""
    if given != (0, 0):
        return Registration(shift_px=(float(given[0]), float(given[1])))
    if mode != "auto" or measured is None or measured.get("registration") is None:
        return Registration()
    gain = measured.get("gain")
    if gain is None or gain <= MIN_GAIN or measured.get("edge_pixels", 0) < MIN_EDGE_PIXELS:
        return Registration()
    return Registration.of_record(measured["registration"])


def registered_depth(frame: Frame, reg: Registration) -> NDArray[np.float32]:
    """``frame``'s depth moved onto its colour image by ``reg``: each depth pixel goes to the
    nearest colour pixel (the nearest surface where several land); where a finer colour grid
    (scale above 1) leaves a pixel between them empty, the nearest of its 3x3 neighbours."""
    reg = reg.at(frame.width, frame.height)
    shift = reg.integer_shift
    if shift is not None:
        return shifted(frame.depth, shift)
    depth = frame.depth
    h, w = depth.shape
    ys, xs = np.nonzero(depth > 0)
    z = depth[ys, xs].astype(np.float64)
    k = frame.intrinsics
    u = _nearest(reg.scale * (xs - k.cx) + k.cx + reg.shift_px[0] + reg.parallax / z)
    v = _nearest(reg.scale * (ys - k.cy) + k.cy + reg.shift_px[1])
    inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    u, v, z = u[inside], v[inside], z[inside]
    order = np.argsort(-z)  # far first: the nearest surface is written last
    out = np.zeros((h, w), dtype=np.float32)
    out[v[order], u[order]] = z[order]
    if reg.scale > 1.0:
        near = cv2.erode(np.where(out > 0, out, np.float32(1e6)), np.ones((3, 3), np.uint8))
        out = np.where((out == 0) & (near < 1e6), near, out).astype(np.float32)
    return out


def colour_pose(frame: Frame, reg: Registration) -> NDArray[np.float64]:
    """The pose of ``frame``'s colour camera: its depth camera's moved by the baseline the
    parallax implies (unchanged without parallax)."""
    reg = reg.at(frame.width, frame.height)
    if reg.parallax == 0.0:
        return frame.c2w
    c2w = frame.c2w.copy()
    c2w[:3, 3] += c2w[:3, 0] * reg.baseline_m(frame.intrinsics.fx)
    return c2w


def registered(frames: Sequence[Frame], reg: Registration) -> tuple[Frame, ...]:
    """``frames`` with their depth moved onto the colour and, with a parallax, their pose
    moved to the colour camera's (unchanged for the identity)."""
    if reg.identity:
        return tuple(frames)
    return tuple(
        replace(f, depth=registered_depth(f, reg), c2w=colour_pose(f, reg)) for f in frames
    )


def report(
    mode: str, given: tuple[int, int], measured: dict[str, Any] | None, applied: Registration
) -> dict[str, Any]:
    """The ``sensor.registration`` entry of ``reconstruction.json``."""
    return {
        "mode": "given" if given != (0, 0) else mode,
        "measured": measured,
        "min_gain": MIN_GAIN,
        "min_edge_pixels": MIN_EDGE_PIXELS,
        "applied_shift_px": [round(v, 3) for v in applied.shift_px],
        "applied": applied.record(),
    }


def log_decision(entry: dict[str, Any]) -> None:
    """One log line: the measured registration, its gain, and what was applied."""
    measured, applied = entry["measured"], entry["applied"]
    moved = applied != Registration().record()
    done = f"depth moved onto the colour ({_describe(applied)})" if moved else "depth as is"
    if entry["mode"] == "given":
        log.info("colour/depth registration: given shift %s px: %s", applied["shift_px"], done)
    elif measured is None:
        log.info("colour/depth registration: not estimated (%s): %s", entry["mode"], done)
    elif measured["registration"] is None:
        log.info("colour/depth registration: no depth edges to measure: %s", done)
    else:
        log.info(
            "colour/depth registration: colour edges sit at %s from the depth edges "
            "(edge contrast +%.1f %% over none, %d edge pixels): %s",
            _describe(measured["registration"]),
            100 * (measured["gain"] or 0.0),
            measured["edge_pixels"],
            done,
        )


def _describe(record: dict[str, Any]) -> str:
    """``shift [dx, dy] px`` plus the scale and parallax where they are not the identity's."""
    text = f"shift {record['shift_px']} px"
    if record["scale"] != 1.0:
        text += f", scale {record['scale']:.4f}"
    if record["parallax_px_m"] != 0.0:
        text += f", parallax {record['parallax_px_m']:.1f} px m"
    return text
