"""Sensor-depth denoising before initialisation and the depth loss: a noise-bounded median.

Depth sensors add noise that grows with the square of the distance (structured light and
time of flight alike); back-projected as it is, a wall 3 m away becomes a shell several
centimetres thick and the Gaussians fitted to it sit off the surface. :func:`denoise_depth`
replaces each valid pixel by the median of the valid pixels in its ``window x window``
neighbourhood, but only where the two differ by at most ``k`` times the view's own noise level
at that depth; elsewhere (depth edges, thin structures the median would erase) the pixel keeps
its value. The noise level ``sigma`` (per metre squared) is measured, not configured, by
:func:`dcseg.reconstruct.depth_noise.view_noise`: plane fits to the inverse depth, net of the
quantisation step. Noise-free depth (rendered captures such as Replica) measures 0 and is
returned as it is, at the cost of the sparse measurement only; noisy depth loses most of its
noise (the median of 25 samples has about a fifth of one sample's deviation).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numba
import numpy as np
from numpy.typing import NDArray

from dcseg.reconstruct.config import ReconstructConfig
from dcseg.reconstruct.depth_noise import quantisation_step, view_noise
from dcseg.reconstruct.flying import drop_flying
from dcseg.types import Frame

Array = Any  # numpy arrays; numba cannot see annotations, mypy cannot see numba


@numba.njit(parallel=True, cache=True, nogil=True)
def window_median(depth: Array, radius: int, step: int, offset: int) -> Array:
    """``([H', W'] median, [H', W'] full)`` on the pixel grid ``offset::step`` of both axes:
    per valid pixel the median of the valid (> 0) depths in its ``(2 radius + 1)`` square
    window of the full-resolution ``depth`` (0 where the pixel is invalid), and whether the
    whole window was valid."""
    h, w = depth.shape
    rows = (h - offset + step - 1) // step
    cols = (w - offset + step - 1) // step
    median = np.zeros((rows, cols), dtype=np.float32)
    full = np.zeros((rows, cols), dtype=np.bool_)
    size = (2 * radius + 1) * (2 * radius + 1)
    for i in numba.prange(rows):
        buf = np.empty(size, dtype=np.float32)
        y = offset + i * step
        for j in range(cols):
            x = offset + j * step
            if depth[y, x] <= 0:
                continue
            n = 0
            for yy in range(max(0, y - radius), min(h, y + radius + 1)):
                for xx in range(max(0, x - radius), min(w, x + radius + 1)):
                    d = depth[yy, xx]
                    if d > 0:
                        m = n  # insertion sort: windows are tiny
                        while m > 0 and buf[m - 1] > d:
                            buf[m] = buf[m - 1]
                            m -= 1
                        buf[m] = d
                        n += 1
            half = n // 2
            median[i, j] = buf[half] if n % 2 == 1 else 0.5 * (buf[half - 1] + buf[half])
            full[i, j] = n == size
    return median, full


def denoise_depth(
    depth: NDArray[np.float32],
    window: int,
    k: float,
    step: int = 1,
    offset: int = 0,
    sigma: float | None = None,
) -> NDArray[np.float32]:
    """The pixels ``depth[offset::step, offset::step]``, each valid one replaced by its window
    median where the two differ by at most ``k x sigma x d^2`` (module docstring); invalid
    pixels (0) stay invalid. Only the returned pixels are filtered, so a subsampled grid costs
    ``1 / step^2`` of the whole image.

    Args:
        depth: ``[H, W]`` float32 metres, 0 = invalid.
        window: odd window edge in pixels (3, 5, ...); 1 returns the grid unfiltered.
        k: how many noise deviations a replacement may move a pixel (> 0).
        step, offset: the returned grid (``step >= 1``, ``0 <= offset < step``).
        sigma: the view's noise at 1 m if already measured (else :func:`view_noise`).

    Returns:
        ``[ceil((H - offset) / step), ceil((W - offset) / step)]`` float32, a new array.
    """
    if window < 1 or window % 2 == 0:
        raise ValueError(f"depth filter window must be an odd number >= 1, got {window}")
    if not k > 0:
        raise ValueError(f"depth filter k must be > 0, got {k}")
    if step < 1 or not 0 <= offset < step:
        raise ValueError(f"need step >= 1 and 0 <= offset < step, got {step}, {offset}")
    d = np.ascontiguousarray(depth, dtype=np.float32)
    grid = d[offset::step, offset::step].copy()
    if window == 1:
        return grid
    sigma = view_noise(d) if sigma is None else sigma
    if sigma == 0.0:  # noise-free (or quantised) depth: nothing to do, and nothing to pay
        return grid
    median, full = window_median(d, window // 2, step, offset)
    z = grid.astype(np.float64)
    near = np.abs(z - median) <= k * sigma * z * z
    return np.where((grid > 0) & near, median, grid)


@dataclass(frozen=True)
class DepthFilter:
    """The filter of :func:`denoise_depth` with its parameters (``window`` 1 = off), after
    dropping flying pixels (:func:`dcseg.reconstruct.flying.drop_flying`) when ``flying``."""

    window: int = 5
    k: float = 5.0
    flying: bool = True

    @classmethod
    def of(cls, cfg: ReconstructConfig) -> DepthFilter:
        """The filter ``cfg`` asks for (``depth_filter_window``, ``depth_filter_k``,
        ``drop_flying_pixels``)."""
        return cls(cfg.depth_filter_window, cfg.depth_filter_k, cfg.drop_flying_pixels)

    def noise(self, frames: Sequence[Frame]) -> float | None:
        """The median of :func:`view_noise` over ``frames`` (metres at 1 m); None when off."""
        if self.window == 1 or not frames:
            return None
        return float(
            np.median([view_noise(np.ascontiguousarray(f.depth, dtype=np.float32)) for f in frames])
        )

    def grid(
        self, depth: NDArray[np.float32], step: int = 1, offset: int = 0
    ) -> NDArray[np.float32]:
        """The filtered pixels ``depth[offset::step, offset::step]``."""
        d = np.ascontiguousarray(depth, dtype=np.float32)
        if not self.flying:
            return denoise_depth(d, self.window, self.k, step, offset)
        sigma = view_noise(d)  # the flying pixels' margins follow the view's noise and steps
        d = drop_flying(d, sigma, quantisation_step(d))
        return denoise_depth(d, self.window, self.k, step, offset, sigma)
