"""Per-pixel blending weights of frozen Gaussians in one view (:class:`dcseg.blend.BlendWeights`).

The per-pixel rules are exactly those of the rasterizer's forward pass (alpha clamp, the 1/255
alpha floor, stopping when transmittance would fall to ``T_MIN``), so
``blend_weights(g, cam).render(v)`` equals ``render(g, v, cam).values`` up to the truncation
below. Two truncations bound memory: contributions with weight below ``min_weight`` are not
stored (their pixel still loses the transmittance), and at most ``max_per_pixel`` are stored
per pixel (front-most first). Storage is 8 bytes per stored contribution plus 8 per pixel.

Each pixel is composited once, into a dense ``[H * W, K]`` buffer (K = ``max_per_pixel``, at most
the longest tile list; 20 MB at 320x240 with K = 32), which is then compacted into the CSR
arrays; the buffer is freed before returning.
"""

from __future__ import annotations

import math
import warnings
from typing import Any

import numba
import numpy as np
import torch
from numba import prange
from numba.core.errors import NumbaPerformanceWarning

from dcseg.blend import BlendWeights
from dcseg.gaussians import Gaussians
from dcseg.render.camera import Camera
from dcseg.render.cpu_projection import project_cpu
from dcseg.render.numba_kernels import bin_tiles
from dcseg.render.projection import ALPHA_MIN, TILE_SIZE, tile_grid
from dcseg.render.torch_renderer import ALPHA_MAX, T_MIN

Array = Any  # numpy arrays; numba cannot see annotations, mypy cannot see numba


def blend_weights(
    gaussians: Gaussians,
    camera: Camera,
    *,
    min_weight: float = 1e-3,
    max_per_pixel: int = 64,
) -> BlendWeights:
    """The blending weights of every Gaussian in every pixel of ``camera``.

    Args:
        gaussians: the (frozen) Gaussians; gradients are not tracked.
        camera: the view.
        min_weight: contributions below this weight are dropped.
        max_per_pixel: at most this many contributions are kept per pixel, front-most first.

    Returns:
        The view's :class:`BlendWeights` on the CPU (ids int32, weights float32).
    """
    with torch.no_grad():
        splats = project_cpu(gaussians.detach().to("cpu"), camera)
    width, height = camera.width, camera.height
    tiles_x, tiles_y = tile_grid(width, height)
    means2d = _numpy(splats.means2d, np.float32)
    conics = _numpy(splats.conics, np.float32)
    opacities = _numpy(splats.opacities, np.float32)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NumbaPerformanceWarning)
        offsets, order = bin_tiles(
            _numpy(splats.tile_min, np.int64), _numpy(splats.tile_max, np.int64),
            tiles_x * tiles_y, tiles_x,
        )  # fmt: skip
        longest = int(np.diff(offsets).max()) if offsets.shape[0] > 1 else 0
        keep = max(1, min(int(max_per_pixel), longest))
        counts, buf_slots, buf_weights = _walk(
            means2d, conics, opacities, offsets, order,
            width, height, tiles_x, float(min_weight), keep,
        )  # fmt: skip
        pixel_offsets = np.zeros(width * height + 1, dtype=np.int64)
        np.cumsum(counts, out=pixel_offsets[1:])
        slots, weights = _compact(buf_slots, buf_weights, pixel_offsets)
    del buf_slots, buf_weights
    gaussian_ids = _numpy(splats.index, np.int64)[slots].astype(np.int32)
    return BlendWeights(
        height=height,
        width=width,
        offsets=torch.from_numpy(pixel_offsets),
        ids=torch.from_numpy(gaussian_ids),
        weights=torch.from_numpy(weights),
    )


def _numpy(t: torch.Tensor, dtype: Any) -> np.ndarray[Any, Any]:
    return np.ascontiguousarray(t.detach().cpu().numpy().astype(dtype, copy=False))


@numba.njit(cache=True, nogil=True)
def _pixel_walk(
    px: int, py: int, means2d: Array, conics: Array, opacities: Array, order: Array,
    start: int, end: int, min_weight: float, slots: Array, weights: Array, row: int,
) -> int:  # fmt: skip
    """Composite one pixel front to back into ``slots[row]`` / ``weights[row]``; return the count.

    Whole arrays and a row index, not row views: views would update the shared arrays'
    reference counts atomically from every thread, once per pixel.
    """
    max_keep = slots.shape[1]
    trans = 1.0
    kept = 0
    for k in range(start, end):
        g = order[k]
        dx = means2d[g, 0] - px
        dy = means2d[g, 1] - py
        a, b, c = conics[g, 0], conics[g, 1], conics[g, 2]
        sigma = 0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy
        alpha = min(ALPHA_MAX, opacities[g] * math.exp(-sigma))
        if sigma < 0.0 or alpha < ALPHA_MIN:
            continue
        next_t = trans * (1.0 - alpha)
        if next_t <= T_MIN:
            break
        weight = alpha * trans
        if weight >= min_weight:
            slots[row, kept] = g
            weights[row, kept] = weight
            kept += 1
            if kept == max_keep:
                break
        trans = next_t
    return kept


@numba.njit(parallel=True, cache=True, nogil=True)
def _walk(
    means2d: Array, conics: Array, opacities: Array, offsets: Array, order: Array,
    width: int, height: int, tiles_x: int, min_weight: float, max_keep: int,
) -> tuple[Array, Array, Array]:  # fmt: skip
    """Per pixel (row-major): the number of stored contributions and the dense buffers."""
    counts = np.zeros(width * height, dtype=np.int64)
    slots = np.empty((width * height, max_keep), dtype=np.int32)
    weights = np.empty((width * height, max_keep), dtype=np.float32)
    for tile in prange(offsets.shape[0] - 1):
        x0, y0 = (tile % tiles_x) * TILE_SIZE, (tile // tiles_x) * TILE_SIZE
        for py in range(y0, min(y0 + TILE_SIZE, height)):
            for px in range(x0, min(x0 + TILE_SIZE, width)):
                p = py * width + px
                counts[p] = _pixel_walk(
                    px, py, means2d, conics, opacities, order, offsets[tile],
                    offsets[tile + 1], min_weight, slots, weights, p,
                )  # fmt: skip
    return counts, slots, weights


@numba.njit(parallel=True, cache=True, nogil=True)
def _compact(buf_slots: Array, buf_weights: Array, pixel_offsets: Array) -> tuple[Array, Array]:
    """The buffers' first ``count`` entries per pixel, in CSR order."""
    nnz = pixel_offsets[-1]
    slots = np.empty(nnz, dtype=np.int64)
    weights = np.empty(nnz, dtype=np.float32)
    for p in prange(buf_slots.shape[0]):
        lo = pixel_offsets[p]
        for k in range(pixel_offsets[p + 1] - lo):
            slots[lo + k] = buf_slots[p, k]
            weights[lo + k] = buf_weights[p, k]
    return slots, weights
