"""Flying pixels: depth samples at a depth edge that belong to neither side of it.

A sensor pixel straddling a depth discontinuity mixes the foreground and the background
(time-of-flight phase mixing, a stereo window over the edge, a bilinear resize of the depth
map): its depth lies in between, on no surface, and back-projected it makes a fringe of
points in free space that Gaussians are then fitted to. Along a row or a column, a pixel ``p``
is *flying* when the pixels ``p - a`` and ``p + b`` (``a, b`` in 1-2, so strips of one or two
mixed pixels are found) differ by a jump ``J`` above :data:`JUMP` of their depth, both sides
are flat beyond them (their next steps are below ``J / 4``, which tells an edge from a steep
slope whose steps go on), and ``p`` is more than ``J / 8`` (and four times the noise plus the
quantisation step) from both sides, plus what each side's slope covers up to ``p``. A pixel
is a *depth-edge pixel* when its two neighbours along a row or column differ by such a jump.
"""

from __future__ import annotations

from typing import Any

import numba
import numpy as np
from numpy.typing import NDArray

Array = Any  # numpy arrays; numba cannot see annotations, mypy cannot see numba

JUMP = 0.05
"""A depth edge is a jump of more than this fraction of the depth (5 cm at 1 m: above the
noise of consumer sensors at their working range, below the gap between most objects)."""


@numba.njit(cache=True, nogil=True, inline="always")
def _flying_along(
    z: float, near: float, far: float, out_near: float, out_far: float, a: int, b: int, floor: float
) -> bool:
    """Whether ``z`` lies inside a jump from ``near`` (``a`` pixels away) to ``far`` (``b``
    pixels away) whose outer neighbours ``out_near``, ``out_far`` continue flat, more than a
    margin (plus each side's slope over the distance) off both sides (0 = invalid, never
    flying)."""
    if near <= 0 or far <= 0 or out_near <= 0 or out_far <= 0:
        return False
    jump = abs(far - near)
    if jump <= JUMP * min(near, far) or jump <= 4.0 * floor:
        return False
    if abs(near - out_near) >= 0.25 * jump or abs(far - out_far) >= 0.25 * jump:
        return False
    margin = max(0.125 * jump, floor)
    if not min(near, far) + margin < z < max(near, far) - margin:
        return False
    # off each side's surface by more than the margin plus what its slope covers to the pixel
    return (
        abs(z - near) > margin + abs(near - out_near) * a
        and abs(z - far) > margin + abs(far - out_far) * b
    )


@numba.njit(parallel=True, cache=True, nogil=True)
def flying_mask(depth: Array, noise: float = 0.0, step: float = 0.0) -> tuple[Array, int]:
    """``([H, W] bool flying pixels, depth-edge pixel count)`` of ``depth`` (metres, 0 =
    invalid), by the rule of the module docstring; no margin is below four times the noise
    ``noise z^2`` plus the quantisation ``step`` at the pixel's depth."""
    h, w = depth.shape
    flying = np.zeros((h, w), dtype=np.bool_)
    edges = 0
    for y in numba.prange(h):
        for x in range(w):
            z = depth[y, x]
            if not z > 0:
                continue
            floor = 4.0 * (noise * z * z + step)
            edge = False
            if 0 < x < w - 1 and depth[y, x - 1] > 0 and depth[y, x + 1] > 0:
                lo, hi = depth[y, x - 1], depth[y, x + 1]
                edge = abs(hi - lo) > max(JUMP * min(lo, hi), 4.0 * floor)
            if not edge and 0 < y < h - 1 and depth[y - 1, x] > 0 and depth[y + 1, x] > 0:
                lo, hi = depth[y - 1, x], depth[y + 1, x]
                edge = abs(hi - lo) > max(JUMP * min(lo, hi), 4.0 * floor)
            if edge:
                edges += 1
            hit = False
            for a in range(1, 3):
                for b in range(1, 4 - a):
                    if not hit and x - a - 1 >= 0 and x + b + 1 < w:
                        row = depth[y]
                        hit = _flying_along(
                            z, row[x - a], row[x + b], row[x - a - 1], row[x + b + 1], a, b, floor
                        )
                    if not hit and y - a - 1 >= 0 and y + b + 1 < h:
                        hit = _flying_along(
                            z,
                            depth[y - a, x],
                            depth[y + b, x],
                            depth[y - a - 1, x],
                            depth[y + b + 1, x],
                            a,
                            b,
                            floor,
                        )
            flying[y, x] = hit
    return flying, edges


def drop_flying(depth: NDArray[Any], noise: float = 0.0, step: float = 0.0) -> NDArray[np.float32]:
    """``depth`` (float32 copy) with its flying pixels (:func:`flying_mask`) set invalid (0)."""
    d = np.ascontiguousarray(depth, dtype=np.float32)
    mask, _ = flying_mask(d, noise, step)
    return np.where(mask, np.float32(0.0), d)


def flying_share(depth: NDArray[Any], noise: float = 0.0, step: float = 0.0) -> tuple[int, int]:
    """``(flying pixels, depth-edge pixels)`` of one depth map (:func:`flying_mask`)."""
    mask, edges = flying_mask(np.ascontiguousarray(depth, dtype=np.float32), noise, step)
    return int(mask.sum()), int(edges)
