"""Wrong intrinsics: the focal length and principal point that make the frames' depth agree.

Users often give a sensor's nominal intrinsics (``585,585,320,240`` for a Kinect) where its
calibrated ones differ by 10 % in focal length and 10-15 px in principal point. Back-projected
with a wrong focal length, every frame's depth becomes a point cloud squeezed or stretched
across the image axes of its own camera; two frames that look at the scene from directions a
few degrees apart then disagree about where its surfaces are, by centimetres, however exact
their poses (a pose error, by contrast, differs from pair to pair). So the intrinsics that
best explain the capture are those under which one frame's depth, projected into another,
agrees with that frame's depth:

* :func:`pairs`: up to :data:`MAX_PAIRS` pairs of training frames spread over the capture, each
  frame with the partner whose viewing direction is closest to :data:`TARGET_DEG` apart
  (between :data:`MIN_DEG` and :data:`MAX_DEG`);
* :func:`disagreement`: the median over pairs of the median relative depth disagreement
  (:func:`dcseg.reconstruct.sensor.pair_disagreement`, occlusions dropped) under a correction;
* :func:`estimate`: a common focal scale (fx and fy) and a principal point shift found by
  coordinate search, coarse then fine; ``auto`` applies them when the disagreement drops by
  more than :data:`MIN_GAIN` (exact intrinsics gain a few per cent from fitting noise).

Captures whose lens is calibrated (distortion given, :mod:`dcseg.lens`) and RGB-only captures
keep their intrinsics. The correction goes to every frame, trained and held out, and to the
later stages through ``poses.json`` (:mod:`dcseg.io.poses`).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from dcseg.reconstruct.registration import finite_numbers, image_size, ratio
from dcseg.reconstruct.sensor import pair_disagreement
from dcseg.types import Frame, Intrinsics

log = logging.getLogger(__name__)

MODES = ("auto", "off")
"""``ReconstructConfig.intrinsics_refinement``: estimate and apply when clear, or not."""

MAX_PAIRS = 24
"""The estimate uses at most this many frame pairs."""

MIN_PAIRS = 4
"""``auto`` corrects nothing measured on fewer overlapping pairs (one pair's pose error could
pass for a focal error)."""

MIN_DEG, TARGET_DEG, MAX_DEG = 3.0, 15.0, 30.0
"""A pair's viewing directions differ by ``MIN_DEG``-``MAX_DEG`` degrees, closest to
``TARGET_DEG``: under a few degrees a wrong focal length barely shows, beyond some tens the
frames see little in common."""

FOCAL_RANGE = (0.8, 1.25)
"""Focal scales searched (times the given focal lengths)."""

PRINCIPAL_RANGE = 0.1
"""Principal point shifts searched, as a fraction of the image width and height."""

MIN_GAIN = 0.3
"""``auto`` applies the estimate when it lowers the depth disagreement by more than this
fraction. Measured (benchmarks/README "Real-sensor detection", ``results/detect_intrinsics.json``;
40 views 320x240, seeds 0-3 and 6): exact intrinsics 0.00-0.01, at heavy noise up to 0.04,
poses off by 0.5 deg / 1 cm up to 0.12; Replica room0 0.07; TUM fr3_cabinet with its own
calibration 0.18 (its keyframe poses are off: tilt 0.9 deg); focal lengths 7-10 % off
0.69-0.79; given 585 px, TUM fr3_cabinet 0.53 and the registered 7-Scenes colour camera 0.68."""


@dataclass(frozen=True)
class Correction:
    """Intrinsics corrected by a common focal scale and a principal point shift of
    ``shift_px`` pixels at an image of ``size`` (width, height); scaled to other sizes.

    ``given``: the ``(fx, fy, cx, cy)`` at ``size`` the correction was measured from, when every
    frame had them. With them the correction is absolute: a capture read later with other
    intrinsics (a run given the scene) still gets the cameras the scene was fitted with,
    instead of correcting the new ones again."""

    focal_scale: float = 1.0
    shift_px: tuple[float, float] = (0.0, 0.0)
    size: tuple[int, int] = (1, 1)
    given: tuple[float, float, float, float] | None = None

    def base(self, k: Intrinsics) -> Intrinsics:
        """What the correction applies to: :attr:`given` at ``k``'s size, else ``k``."""
        if self.given is None:
            return k
        return Intrinsics(*self.given, *self.size).scaled(k.width, k.height)

    def replaces(self, k: Intrinsics) -> bool:
        """Whether ``k`` differs from :attr:`given` (by more than 0.5 px in a focal length or
        the principal point at ``k``'s size): the correction then replaces it."""
        base = self.base(k)
        return any(abs(a - b) > 0.5 for a, b in zip(
            (k.fx, k.fy, k.cx, k.cy), (base.fx, base.fy, base.cx, base.cy), strict=True
        ))  # fmt: skip

    def apply(self, k: Intrinsics) -> Intrinsics:
        """``k`` corrected (the shift scaled by ``k``'s size over :attr:`size`)."""
        k = self.base(k)
        dx = self.shift_px[0] * k.width / self.size[0]
        dy = self.shift_px[1] * k.height / self.size[1]
        s = self.focal_scale
        return replace(k, fx=k.fx * s, fy=k.fy * s, cx=k.cx + dx, cy=k.cy + dy)

    def record(self) -> dict[str, Any]:
        """The JSON form (``poses.json`` ``intrinsics``, ``reconstruction.json``)."""
        entry: dict[str, Any] = {
            "focal_scale": round(self.focal_scale, 6),
            "principal_shift_px": [round(v, 3) for v in self.shift_px],
            "at_size": list(self.size),
        }
        if self.given is not None:
            entry["given"] = [round(v, 4) for v in self.given]
        return entry

    @classmethod
    def of_record(cls, record: Mapping[str, Any]) -> Correction:
        """The correction of :meth:`record`'s output; ValueError naming the bad field."""
        if not isinstance(record, Mapping):
            raise ValueError("the correction must be an object")
        scale = ratio(record.get("focal_scale"), "focal_scale")
        shift: Any = record.get("principal_shift_px")
        if not finite_numbers(shift, 2):
            raise ValueError('"principal_shift_px" must be two finite numbers')
        size = image_size(record.get("at_size"))
        given: Any = record.get("given")
        if given is not None and not (finite_numbers(given, 4) and min(given[:2]) > 0):
            raise ValueError('"given" must be four finite numbers fx fy cx cy, focals > 0')
        known = None if given is None else (float(given[0]), float(given[1]),
                                             float(given[2]), float(given[3]))  # fmt: skip
        return cls(scale, (float(shift[0]), float(shift[1])), size, known)


def corrected(frames: Sequence[Frame], correction: Correction | None) -> tuple[Frame, ...]:
    """``frames`` with their intrinsics corrected (unchanged for None)."""
    if correction is None:
        return tuple(frames)
    return tuple(replace(f, intrinsics=correction.apply(f.intrinsics)) for f in frames)


def pairs(frames: Sequence[Frame]) -> list[tuple[int, int]]:
    """Up to :data:`MAX_PAIRS` index pairs: frames evenly spread over ``frames``, each with the
    frame whose viewing direction is closest to :data:`TARGET_DEG` away (none outside
    :data:`MIN_DEG`-:data:`MAX_DEG`); a pair is kept once."""
    n = len(frames)
    axes = np.stack([f.c2w[:3, 2] for f in frames]) if n else np.zeros((0, 3))
    found: list[tuple[int, int]] = []
    for i in np.unique(np.linspace(0, n - 1, min(MAX_PAIRS, n)).round().astype(int)):
        cos = np.clip(axes @ axes[i], -1.0, 1.0)
        deg = np.degrees(np.arccos(cos))
        fits = (deg >= MIN_DEG) & (deg <= MAX_DEG)
        if not fits.any():
            continue
        j = int(np.argmin(np.where(fits, np.abs(deg - TARGET_DEG), np.inf)))
        pair = (min(int(i), j), max(int(i), j))
        if pair not in found:
            found.append(pair)
    return found


def disagreement(
    frames: Sequence[Frame], chosen: Sequence[tuple[int, int]], correction: Correction
) -> float | None:
    """Median over ``chosen`` pairs of the median of ``|projected - observed| / observed``
    depth with ``correction`` applied to both frames; None when no pair overlaps."""
    values = []
    for i, j in chosen:
        first, second = corrected((frames[i], frames[j]), correction)
        pair = pair_disagreement(first, second)
        if pair is not None:
            values.append(float(np.median(np.abs(pair[0]) / pair[1])))
    return float(np.median(values)) if values else None


def _search(
    frames: Sequence[Frame], chosen: Sequence[tuple[int, int]], size: tuple[int, int]
) -> tuple[Correction, float]:
    """The correction with the lowest :func:`disagreement`: focal scale, then the principal
    point's x and y, coarse over the whole range, then twice finer around the best."""
    best = Correction(size=size)

    def cost(c: Correction) -> float:
        value = disagreement(frames, chosen, c)
        return np.inf if value is None else value

    w, h = size
    rounds = (
        (np.arange(FOCAL_RANGE[0], FOCAL_RANGE[1] + 1e-9, 0.01), PRINCIPAL_RANGE, 2.0),
        (np.arange(-0.02, 0.02 + 1e-9, 0.002), 0.01, 0.5),
    )
    for index, (scales, span, step) in enumerate(rounds):
        focal = scales if index == 0 else best.focal_scale + scales
        best = min((replace(best, focal_scale=float(s)) for s in focal), key=cost)
        dx0, dy0 = best.shift_px
        xs = dx0 + np.arange(-span * w, span * w + 1e-9, step)
        best = min((replace(best, shift_px=(float(x), dy0)) for x in xs), key=cost)
        ys = dy0 + np.arange(-span * h, span * h + 1e-9, step)
        best = min((replace(best, shift_px=(best.shift_px[0], float(y))) for y in ys), key=cost)
    return best, cost(best)


def _shared(frames: Sequence[Frame]) -> tuple[float, float, float, float] | None:
    """The ``(fx, fy, cx, cy)`` every frame has (all of one size), else None."""
    values = {(f.width, f.height, f.intrinsics.fx, f.intrinsics.fy, f.intrinsics.cx,
               f.intrinsics.cy) for f in frames}  # fmt: skip
    if len(values) != 1:
        return None
    _, _, fx, fy, cx, cy = values.pop()
    return (fx, fy, cx, cy)


def estimate(frames: Sequence[Frame]) -> dict[str, Any]:
    """The correction that best makes pairs of ``frames`` agree (module docstring), the
    disagreement before and after, and the gain; ``correction`` None without usable pairs."""
    chosen = pairs(frames)
    given = disagreement(frames, chosen, Correction()) if chosen else None
    if given is None:
        return {"pairs": 0, "correction": None, "gain": None}
    size = (frames[0].width, frames[0].height)
    best, after = _search(frames, chosen, size)
    best = replace(best, given=_shared(frames))
    return {
        "pairs": len(chosen),
        "disagreement_given": round(given, 6),
        "disagreement_fitted": round(after, 6),
        "correction": best.record(),
        "gain": round(1.0 - after / given, 4) if given > 0 else 0.0,
    }


def decide(mode: str, measured: Mapping[str, Any] | None) -> Correction | None:
    """The correction applied: in ``auto`` the measured one when it gains more than
    :data:`MIN_GAIN` on at least :data:`MIN_PAIRS` pairs; else none."""
    if mode != "auto" or measured is None or measured.get("correction") is None:
        return None
    gain = measured.get("gain")
    if gain is None or gain <= MIN_GAIN or measured.get("pairs", 0) < MIN_PAIRS:
        return None
    return Correction.of_record(measured["correction"])


def report(mode: str, measured: Mapping[str, Any] | None, applied: Correction | None,
           why_not: str | None = None) -> dict[str, Any]:  # fmt: skip
    """The ``sensor.intrinsics`` entry of ``reconstruction.json``."""
    entry: dict[str, Any] = {
        "mode": mode,
        "measured": None if measured is None else dict(measured),
        "min_gain": MIN_GAIN,
        "applied": None if applied is None else applied.record(),
    }
    if why_not is not None:
        entry["not_measured"] = why_not
    return entry


def log_decision(entry: Mapping[str, Any], given: Intrinsics) -> None:
    """One log line: what was measured and what the intrinsics are now."""
    measured, applied = entry["measured"], entry["applied"]
    if measured is None:
        log.info("intrinsics: not checked (%s)", entry.get("not_measured", entry["mode"]))
        return
    if measured["correction"] is None:
        log.info("intrinsics: not checked (no two training frames %g-%g deg apart see the "
                 "same surfaces)", MIN_DEG, MAX_DEG)  # fmt: skip
        return
    fitted = Correction.of_record(measured["correction"]).apply(given)
    done = "kept as given"
    if applied is not None:
        done = f"now fx {fitted.fx:.1f} fy {fitted.fy:.1f} cx {fitted.cx:.1f} cy {fitted.cy:.1f}"
    log.info(
        "intrinsics: depth of %d frame pairs agrees best at fx %.1f fy %.1f cx %.1f cy %.1f "
        "(given %.1f %.1f %.1f %.1f): disagreement %.2f %% -> %.2f %% of the depth (%s): %s",
        measured["pairs"], fitted.fx, fitted.fy, fitted.cx, fitted.cy,
        given.fx, given.fy, given.cx, given.cy,
        100 * measured["disagreement_given"], 100 * measured["disagreement_fitted"],
        entry["mode"], done,
    )  # fmt: skip
