"""Sensor depth noise and quantisation, measured from the depth maps themselves.

Structured-light and time-of-flight sensors have depth noise that grows with the square of the
distance, ``sigma(z) = a z^2``: their error is (close to) constant in disparity, that is in
inverse depth ``1 / z``. Real sensors also quantise depth (a 16-bit PNG in millimetres, a
Replica PNG in 1/6553.5 m) and their noise is spatially correlated (a Kinect's block matching
makes plateaus several pixels wide), so a per-pixel comparison with a small window's median
measures 0 on real captures. The estimate here:

1. :func:`quantisation_step`: the step of the lattice the valid depths lie on (0 when they do
   not lie on one), from the gaps between the sorted distinct values of a sample; and
   :func:`disparity_step`, the same for the inverse depths (sensors that quantise disparity,
   as Kinect v1 does: depth steps growing with ``z^2``), reported beside it.
2. :func:`plane_residuals`: on a sparse grid of ``(2 r + 1)^2`` windows with every pixel valid,
   a least-squares plane fitted to the *inverse* depth (a plane in space is exactly a plane in
   ``1 / z`` over the pixel grid, so slanted walls leave no residual) and its residual standard
   deviation (``n - 3`` degrees of freedom), which estimates ``a`` directly. Windows of 15 x 15
   samples of every other pixel span a Kinect's plateaus; windows across depth edges or
   curved surfaces only add variance.
3. :func:`noise_model`: ``a`` from the lower quartile (:data:`QUANTILE`) over all windows of
   the residual variance minus the quantisation's own ``q^2 / 12`` (in inverse depth
   ``q^2 / (12 z^4)``), scaled by the same quartile of pure noise's ``chi2`` distribution: in
   inverse depth the noise is the same at every distance, so all windows pool (binned by
   depth, windows across edges would make up whole bins of intermediate depth), and up to
   three quarters of them may be contaminated. Noise below :data:`NEGLIGIBLE` measures 0. Per
   depth bin the same quartile gives ``sigma(z)`` to check the ``z^2`` law against.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numba
import numpy as np
from numpy.typing import NDArray
from scipy.stats import chi2

Array = Any  # numpy arrays; numba cannot see annotations, mypy cannot see numba

RADIUS = 7
"""Plane-fit windows are ``2 RADIUS + 1`` pixels square (15 x 15)."""

STRIDE = 2
"""The windows sample every other pixel (29 x 29 pixels). On 10 Replica room0 depth maps with
noise correlated over 8 x 8 pixel blocks added (a = 3 mm, mm steps): 2.53 mm with it, 1.19 mm
with every pixel (15 x 15 pixels), 2.83 mm with every third; the noise-free maps measure 0
with each (with the median instead of :data:`QUANTILE`, 0.13 mm with every third: wider
windows cross more edges and curved objects)."""

NEGLIGIBLE = 1e-4
"""Noise below this at 1 m (0.1 mm) measures 0: no median filter improves on it, and it is
what curved surfaces leave in a window of noise-free depth."""

GRID = 8
"""Window centres on every this-many-th pixel of both axes."""

SAMPLE_STEP = 4
"""The quantisation step is read from every this-many-th pixel of both axes."""

MIN_STEP = 1e-6
"""Lattice steps below this (metres) are float rounding, not quantisation."""

LATTICE_TOLERANCE = 0.1
"""Depths lie on a lattice when 95 % of them are within this fraction of a step of it."""

REFINEMENTS = 3
"""Rounds of refining a lattice's step from the gaps that are near multiples of it: a wide gap
(a depth range the image does not show) only counts once the step is close."""

FAR_QUANTILE = 0.8
"""A disparity lattice is read from the distinct depths beyond this quantile of them. On 20
7-Scenes redkitchen frames (Kinect v1, millimetre PNGs): beyond the median 13 find it, beyond
0.8 all 20 (0.002894-0.002898 / m); nearer depths' millimetre rounding is up to a tenth of a
step in inverse depth."""

MIN_DISPARITY_VALUES = 8
"""Distinct depths beyond :data:`FAR_QUANTILE` needed to read a disparity lattice from."""

BINS = 8
"""Depth bins of the reported ``sigma(z)`` (fewer when there are few windows)."""

QUANTILE = 0.25
"""The noise is read from this quantile of the windows' residual variances, not their median:
windows across edges and curved surfaces only ever add variance, and at 600x340 half of
Replica room0's windows have some (median 0.40 mm at 1 m for noise-free depth, lower quartile
0.03 mm). On noise correlated over 8 x 8 pixel plateaus (a = 3 mm) the quartile reads 2.4 mm,
the median 2.8; on the real Kinect frames of benchmarks/README 1.39 and 1.57 mm."""

MIN_WINDOWS = 20
"""Windows per estimate at least (and per reported depth bin); fewer give no estimate."""


def quantisation_step(depth: NDArray[Any]) -> float:
    """The step (metres) of the lattice the valid (> 0) depths of ``depth`` lie on, from every
    :data:`SAMPLE_STEP`-th pixel; 0.0 for continuous depth (or too few distinct values)."""
    values = np.asarray(depth, dtype=np.float64)[::SAMPLE_STEP, ::SAMPLE_STEP]
    return lattice_step(np.unique(values[values > 0]))


def disparity_step(depth: NDArray[Any]) -> float:
    """The step (1 / metres) of the lattice the inverse of the valid depths of ``depth`` lie on:
    a sensor that quantises disparity (Kinect v1: depth steps ``c z^2``, 3 mm at 1 m and 19 mm
    at 2.5 m) and writes the depth rounded to millimetres. Read from the farthest distinct
    depths (beyond their :data:`FAR_QUANTILE`), where the depth steps are widest against that
    rounding; 0.0 when they lie on no such lattice (or are too few)."""
    values = np.asarray(depth, dtype=np.float64)[::SAMPLE_STEP, ::SAMPLE_STEP]
    distinct = np.unique(values[values > 0])
    far = distinct[distinct >= np.quantile(distinct, FAR_QUANTILE)] if len(distinct) else distinct
    if len(far) < MIN_DISPARITY_VALUES:
        return 0.0
    return lattice_step(np.sort(1.0 / far))


def lattice_step(distinct: NDArray[np.float64]) -> float:
    """The step of the lattice the sorted ``distinct`` values lie on (0.0 when they do not,
    within :data:`LATTICE_TOLERANCE`, or there are fewer than 3)."""
    if len(distinct) < 3:
        return 0.0
    gaps = np.diff(distinct)
    gaps = gaps[gaps > MIN_STEP]
    if len(gaps) == 0:
        return 0.0
    step = float(np.percentile(gaps, 5))
    for _ in range(REFINEMENTS):  # float32 rounding blurs single gaps; their sum does not drift
        multiple = np.round(gaps / step)
        near = (multiple >= 1) & (np.abs(gaps / step - multiple) < 0.25)
        if not near.any():
            break
        step = float(gaps[near].sum() / multiple[near].sum())
    ratio = (distinct - distinct[0]) / step
    off = np.abs(ratio - np.round(ratio))
    return 0.0 if float(np.percentile(off, 95)) > LATTICE_TOLERANCE else step


@numba.njit(cache=True, nogil=True)
def plane_residuals(depth: Array, radius: int, grid: int, stride: int) -> tuple[Array, Array]:
    """``([M] mean depth, [M] residual sd)`` of the windows centred on every ``grid``-th pixel
    whose ``(2 radius + 1)^2`` samples (every ``stride``-th pixel) are all valid: the residual
    standard deviation of a least-squares plane fitted to ``1 / depth`` over the samples
    (``n - 3`` degrees of freedom)."""
    h, w = depth.shape
    reach = radius * stride
    side = 2 * radius + 1
    n = side * side
    # a full symmetric window makes 1, u and v orthogonal: each coefficient is a projection
    suu = 0.0
    for k in range(-radius, radius + 1):
        suu += k * k * side
    cap = ((h - 2 * reach) // grid + 1) * ((w - 2 * reach) // grid + 1)
    means = np.empty(max(cap, 0), dtype=np.float64)
    sds = np.empty(max(cap, 0), dtype=np.float64)
    m = 0
    for y in range(reach, h - reach, grid):
        for x in range(reach, w - reach, grid):
            full = True
            sw = 0.0
            swu = 0.0
            swv = 0.0
            sww = 0.0
            sz = 0.0
            for dy in range(-radius, radius + 1):
                for dx in range(-radius, radius + 1):
                    z = depth[y + dy * stride, x + dx * stride]
                    if not z > 0:
                        full = False
                        break
                    iz = 1.0 / z
                    sw += iz
                    swu += iz * dx
                    swv += iz * dy
                    sww += iz * iz
                    sz += z
                if not full:
                    break
            if not full:
                continue
            rss = sww - sw * sw / n - swu * swu / suu - swv * swv / suu
            means[m] = sz / n
            sds[m] = np.sqrt(max(rss, 0.0) / (n - 3))
            m += 1
    return means[:m], sds[:m]


@dataclass(frozen=True)
class NoiseModel:
    """Depth noise ``sigma(z) = a z^2`` and the quantisation step, as measured.

    Attributes:
        a: the noise at 1 m (metres; ``a z^2`` at depth ``z``); 0.0 when the noise is below
            what the quantisation leaves, None when no window could be measured.
        step: the quantisation step (metres), 0.0 for continuous depth.
        disparity_step: the step of the inverse depth's lattice (1 / metres: depth steps of
            ``disparity_step z^2``), 0.0 when the depth does not lie on one. Such steps are
            uniform in disparity like the noise, so ``a`` holds them (no filter or check needs
            them apart); they are reported, not subtracted.
        bins: per depth bin ``(median depth, noise at that depth, windows)``: the measured
            ``sigma(z)``, to check the ``z^2`` law against.
    """

    a: float | None
    step: float
    bins: tuple[tuple[float, float, int], ...]
    disparity_step: float = 0.0

    def as_dict(self) -> dict[str, Any]:
        """The model for ``reconstruction.json``; ``units_per_metre`` is the depth scale the
        step implies (1000 for millimetre PNGs, 6553.5 for Replica's), None when continuous."""
        return {
            "model": "sigma(z) = a z^2",
            "a_at_1m": self.a,
            "quantisation_step": self.step,
            "units_per_metre": round(1.0 / self.step, 1) if self.step > 0 else None,
            "disparity_step": self.disparity_step,
            "bins": [{"depth": z, "sigma": s, "windows": n} for z, s, n in self.bins],
        }


FALLBACKS = ((RADIUS, 1), (3, 1))
"""Smaller windows (radius, stride), tried in turn when depth maps are too small or too holed
for :data:`MIN_WINDOWS` whole windows."""


def noise_model(
    depths: Sequence[NDArray[Any]],
    step: float | None = None,
    radius: int = RADIUS,
    stride: int = STRIDE,
    disparity: bool = True,
) -> NoiseModel:
    """The noise model pooled over ``depths`` (``[H, W]`` metres, 0 = invalid) with windows of
    ``radius`` and ``stride`` (then :data:`FALLBACKS`); ``step`` the quantisation step if known
    (else the median of :func:`quantisation_step` over them); ``disparity``: read the
    disparity lattice too (else ``disparity_step`` is 0.0: unread)."""
    if step is None:
        step = float(np.median([quantisation_step(d) for d in depths])) if depths else 0.0
    read = disparity and bool(depths)
    c = float(np.median([disparity_step(d) for d in depths])) if read else 0.0
    maps = [np.ascontiguousarray(d, np.float32) for d in depths]
    z, sd, dof = np.zeros(0), np.zeros(0), 1
    for r, s in ((radius, stride), *FALLBACKS):
        parts = [plane_residuals(d, r, GRID, s) for d in maps]
        z = np.concatenate([p[0] for p in parts]) if parts else np.zeros(0)
        sd = np.concatenate([p[1] for p in parts]) if parts else np.zeros(0)
        dof = (2 * r + 1) ** 2 - 3
        if len(z) >= MIN_WINDOWS:
            break
    if len(z) < MIN_WINDOWS:
        return NoiseModel(None, step, (), c)
    # the residual variance net of the quantisation's (q^2 / 12 in depth, / z^4 in 1 / depth)
    net = sd * sd - step * step / (12.0 * z**4)
    a = _quantile_sd(net, dof)
    return NoiseModel(a if a >= NEGLIGIBLE else 0.0, step, _bins(z, net, dof), c)


def _quantile_sd(net: NDArray[np.float64], dof: int) -> float:
    """The noise the :data:`QUANTILE` of the windows' residual variances ``net`` implies: that
    quantile over the same quantile of ``chi2(dof) / dof`` (what pure noise would give)."""
    scale = float(chi2.ppf(QUANTILE, dof)) / dof
    return float(np.sqrt(max(float(np.quantile(net, QUANTILE)) / scale, 0.0)))


def _bins(
    z: NDArray[np.float64], net: NDArray[np.float64], dof: int
) -> tuple[tuple[float, float, int], ...]:
    """Per depth bin (quantiles of ``z``) the median depth, ``sigma(z)`` and its windows."""
    count = max(1, min(BINS, len(z) // MIN_WINDOWS))
    edges = np.quantile(z, np.linspace(0.0, 1.0, count + 1))
    which = np.clip(np.searchsorted(edges, z, side="right") - 1, 0, count - 1)
    out = []
    for b in range(count):
        inside = which == b
        zb = float(np.median(z[inside]))
        a_b = _quantile_sd(net[inside], dof)
        out.append((zb, a_b * zb * zb, int(inside.sum())))
    return tuple(out)


def view_noise(depth: NDArray[Any]) -> float:
    """One view's noise at 1 m (:func:`noise_model` of that view alone; 0.0 when unmeasured;
    the disparity lattice, which ``a`` does not depend on, is not read: the depth filter calls
    this for every training view)."""
    a = noise_model([depth], disparity=False).a
    return 0.0 if a is None else a
