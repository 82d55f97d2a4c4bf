"""Noise levels for simulated segmenter output and depth, and the depth-noise model."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray


@dataclass(frozen=True)
class Failures:
    """Consistent segmenter failures (the ``realistic`` level); probabilities per instance
    unless stated otherwise.

    Attributes:
        lookalike_prob: chance an object or table is taken for one of its look-alikes
            (:data:`~dcseg.synth.failures.LOOKALIKES`).
        lookalike_view_prob: per view, chance such an instance shows its look-alike class
            (the rest of the views are right): most views agree on the mistake.
        rare_miss_prob: chance a rare-class object
            (:data:`~dcseg.synth.catalogue.RARE_CLASSES`) is missed in every view (it takes
            its support's class: maps never abstain).
        swallow_fraction: per view, objects covering less than this fraction of the image take
            their support's class.
        class_factor: class maps are predicted at 1/``class_factor`` resolution and upsampled
            by repetition.
        never_abstain: every pixel gets a class (unlabelled pixels take the nearest label).
        mask_factor: class-agnostic masks are computed at 1/``mask_factor`` resolution.
        merge_prob: per view and pair of touching objects, chance they share one mask.
        uncovered: per view, the fraction of visible objects that get no mask is drawn
            uniformly from this range.
    """

    lookalike_prob: float = 0.5
    lookalike_view_prob: float = 0.8
    rare_miss_prob: float = 0.7
    swallow_fraction: float = 0.0015
    class_factor: int = 4
    never_abstain: bool = True
    mask_factor: int = 2
    merge_prob: float = 0.5
    uncovered: tuple[float, float] = (0.1, 0.3)

    def __post_init__(self) -> None:
        for name in ("lookalike_prob", "lookalike_view_prob", "rare_miss_prob", "merge_prob"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"{name} must be in [0, 1], got {getattr(self, name)}")
        if self.class_factor < 1 or self.mask_factor < 1:
            raise ValueError("class_factor and mask_factor must be >= 1")
        lo, hi = self.uncovered
        if not 0.0 <= lo <= hi < 1.0:
            raise ValueError(f"uncovered must be a range within [0, 1), got {self.uncovered}")


@dataclass(frozen=True)
class NoiseLevel:
    """How imperfect the simulated 2D masks and depth are (all probabilities are per view).

    Attributes:
        part_prob: chance an object also gets two part masks (split by a 3D plane).
        group_prob: chance a support (table, tray) also gets a mask uniting it with its objects.
        wall_split_prob: chance a wall/floor mask is over-split into 2-4 pieces.
        jitter_prob: chance a mask's boundary is dilated or eroded.
        jitter_px: largest boundary dilation/erosion in pixels.
        miss_prob: chance any agnostic mask is dropped.
        spurious_rate: mean number of spurious elliptical blobs per view.
        bleed_prob: chance a class bleeds into its neighbours in the class map.
        bleed_px: largest bleeding distance in pixels.
        confuse_prob: chance a whole instance gets its confusable class in a view.
        rare_miss_prob: chance a rare-class instance is unlabelled or mislabelled in a view.
        hole_rate: mean number of unlabelled (-1) elliptical holes per view.
        depth_sigma: Gaussian depth noise standard deviation at 1 m (grows with z squared).
        edge_drop_prob: chance a pixel at a depth discontinuity loses its depth.
        random_drop_prob: chance any pixel loses its depth.
        disparity_step: the depth is quantised in disparity as Kinect v1 quantises it: inverse
            depth rounded to multiples of this step (1 / metres; depth steps of
            ``disparity_step z^2``, 2.9 mm at 1 m and 18 mm at 2.5 m for 0.0029, what
            7-Scenes' Kinect v1 depth shows). 0 = not quantised (the capture's millimetres).
        failures: consistent segmenter failures (:mod:`dcseg.synth.failures`) on top of the
            per-view noise above; None = none (the per-view noise alone).
    """

    part_prob: float = 0.0
    group_prob: float = 0.0
    wall_split_prob: float = 0.0
    jitter_prob: float = 0.0
    jitter_px: int = 0
    miss_prob: float = 0.0
    spurious_rate: float = 0.0
    bleed_prob: float = 0.0
    bleed_px: int = 0
    confuse_prob: float = 0.0
    rare_miss_prob: float = 0.0
    hole_rate: float = 0.0
    depth_sigma: float = 0.0
    edge_drop_prob: float = 0.0
    random_drop_prob: float = 0.0
    disparity_step: float = 0.0
    failures: Failures | None = None


NOISE_LEVELS: dict[str, NoiseLevel] = {
    "clean": NoiseLevel(),
    "default": NoiseLevel(
        part_prob=0.35,
        group_prob=0.3,
        wall_split_prob=0.5,
        jitter_prob=0.5,
        jitter_px=2,
        miss_prob=0.1,
        spurious_rate=1.0,
        bleed_prob=0.5,
        bleed_px=2,
        confuse_prob=0.12,
        rare_miss_prob=0.6,
        hole_rate=1.0,
        depth_sigma=0.0015,
        edge_drop_prob=0.5,
        random_drop_prob=0.002,
    ),
    "heavy": NoiseLevel(
        part_prob=0.6,
        group_prob=0.5,
        wall_split_prob=0.8,
        jitter_prob=0.8,
        jitter_px=3,
        miss_prob=0.25,
        spurious_rate=3.0,
        bleed_prob=0.8,
        bleed_px=4,
        confuse_prob=0.35,
        rare_miss_prob=0.85,
        hole_rate=3.0,
        depth_sigma=0.004,
        edge_drop_prob=0.9,
        random_drop_prob=0.01,
    ),
    "realistic": NoiseLevel(
        part_prob=0.7,
        group_prob=0.7,
        wall_split_prob=0.5,
        jitter_prob=0.5,
        jitter_px=2,
        miss_prob=0.05,
        spurious_rate=1.5,
        bleed_prob=0.5,
        bleed_px=2,
        confuse_prob=0.05,
        depth_sigma=0.0015,
        edge_drop_prob=0.5,
        random_drop_prob=0.002,
        failures=Failures(),
    ),
}
"""The named noise levels of ``dcseg synth --noise``."""


def noisy_depth(
    depth: NDArray[np.float32], level: NoiseLevel, rng: np.random.Generator
) -> NDArray[np.float32]:
    """Sensor-like depth: z-dependent Gaussian noise, holes at discontinuities and at random.

    Args:
        depth: ``[H, W]`` clean metric depth, 0 = invalid.
        level: the noise level.
        rng: seeded generator for this view.

    Returns:
        ``[H, W]`` float32 depth, 0 = invalid (never negative).
    """
    out = depth.astype(np.float64)
    valid = out > 0
    if level.depth_sigma > 0:
        out = out + rng.normal(0.0, 1.0, out.shape) * level.depth_sigma * out * out
    if level.disparity_step > 0:
        out = disparity_quantised(out, level.disparity_step)
    drop = rng.random(out.shape) < level.random_drop_prob
    if level.edge_drop_prob > 0:
        drop |= _depth_edges(depth) & (rng.random(out.shape) < level.edge_drop_prob)
    out[drop | ~valid] = 0.0
    return np.maximum(out, 0.0).astype(np.float32)


DISPARITY_OFFSET = 0.37
"""Where the disparity lattice starts, in steps: a sensor's lattice need not meet 1 / z = 0."""


def disparity_quantised(depth: NDArray[np.float64], step: float) -> NDArray[np.float64]:
    """``depth`` (metres, > 0 where valid) with its inverse rounded to multiples of ``step``
    (1 / metres) from :data:`DISPARITY_OFFSET` steps; invalid and unrepresentable (beyond the
    lattice's first level) stay or become 0."""
    offset = DISPARITY_OFFSET * step
    valid = depth > 0
    inverse = np.round((1.0 / np.where(valid, depth, 1.0) - offset) / step) * step + offset
    ok = valid & (inverse > offset)
    return np.where(ok, 1.0 / np.where(ok, inverse, 1.0), 0.0)


def _depth_edges(depth: NDArray[np.float32], jump: float = 0.05) -> NDArray[np.bool_]:
    """Pixels next to a depth jump larger than ``jump`` times the depth (or to invalid depth)."""
    d = depth.astype(np.float64)
    edges = np.zeros(d.shape, dtype=bool)
    dy = np.abs(np.diff(d, axis=0)) > jump * np.maximum(d[1:], d[:-1])
    dx = np.abs(np.diff(d, axis=1)) > jump * np.maximum(d[:, 1:], d[:, :-1])
    edges[1:] |= dy
    edges[:-1] |= dy
    edges[:, 1:] |= dx
    edges[:, :-1] |= dx
    return edges
