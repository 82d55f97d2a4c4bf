"""numba kernels of the ``cpu`` backend: tile binning, forward and analytic backward.

The loops are those of the 3DGS / gsplat CUDA rasterizer, reorganised for CPU cores: one
``prange`` iteration per worker thread, each compositing its share of the 16x16 tiles (shares
balanced by the tiles' list lengths, see :func:`balanced_tiles`); inside a tile the *splats*
are the outer loop (front to back in the forward, back to front in the backward) and only the
pixels of the splat's alpha >= 1/255 bounding box are visited, with per-pixel state
(transmittance, done flag) kept in small tile-local arrays. Skipping pixels outside that box is
exact: there the alpha test would reject the splat anyway.

Backward gradients are written per (tile, splat) intersection, never shared between tiles, so
the parallel loop has no races and the result is deterministic; the caller sums them per splat.

Arithmetic runs in the values' dtype: pixel coordinates and constants are converted once
(:func:`_typed`), so float32 inputs use float32 ``exp`` instead of being promoted to float64 by
the int64 pixel indices. Pixels farther from a splat's centre than its alpha >= 1/255 ellipse
(plus a margin far above rounding) skip the ``exp``: the alpha test would reject them anyway.

Private module; arrays are float32 or float64 (one compiled specialisation each).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, TypeVar, cast

import numba
import numpy as np
from numba import prange

from dcseg.render.projection import ALPHA_MIN, TILE_SIZE
from dcseg.render.torch_renderer import ALPHA_MAX, T_MIN

_F = TypeVar("_F", bound=Callable[..., Any])
Array = Any  # numpy arrays; numba cannot see annotations, mypy cannot see numba


def _jit(parallel: bool) -> Callable[[_F], _F]:
    return cast(
        Callable[[_F], _F], numba.njit(parallel=parallel, cache=True, fastmath=False, nogil=True)
    )


@_jit(parallel=False)
def bin_tiles(tile_min: Array, tile_max: Array, n_tiles: int, tiles_x: int) -> tuple[Array, Array]:
    """Per-tile lists of splat ids, in splat (= depth) order.

    Args:
        tile_min: ``[M, 2]`` int64 first tile (x, y) of each splat.
        tile_max: ``[M, 2]`` int64 one past the last tile (x, y).
        n_tiles: number of tiles.
        tiles_x: tiles per row.

    Returns:
        ``offsets [n_tiles + 1]`` int64 and ``ids [n_isect]`` int32; tile t's splats are
        ``ids[offsets[t]:offsets[t + 1]]``.
    """
    counts = np.zeros(n_tiles + 1, dtype=np.int64)
    for g in range(tile_min.shape[0]):
        for ty in range(tile_min[g, 1], tile_max[g, 1]):
            for tx in range(tile_min[g, 0], tile_max[g, 0]):
                counts[ty * tiles_x + tx + 1] += 1
    offsets = np.cumsum(counts)
    cursor = offsets[:-1].copy()
    ids = np.empty(offsets[-1], dtype=np.int32)
    for g in range(tile_min.shape[0]):
        for ty in range(tile_min[g, 1], tile_max[g, 1]):
            for tx in range(tile_min[g, 0], tile_max[g, 0]):
                t = ty * tiles_x + tx
                ids[cursor[t]] = g
                cursor[t] += 1
    return offsets, ids


@_jit(parallel=False)
def balanced_tiles(offsets: Array, workers: int) -> tuple[Array, Array]:
    """Split the tiles among ``workers`` threads with near-equal work (longest first, greedy).

    A tile's cost is its splat-list length plus a constant for its pixels. A plain ``prange``
    over tiles hands each thread one contiguous block of rows, and the busier half of an image
    then keeps one core working while the other idles.

    Returns:
        ``order [n_tiles]`` int64 and ``starts [workers + 1]`` int64: worker w composites tiles
        ``order[starts[w]:starts[w + 1]]``.
    """
    n_tiles = offsets.shape[0] - 1
    cost = (offsets[1:] - offsets[:-1]) + 32
    owner = np.empty(n_tiles, dtype=np.int64)
    load = np.zeros(workers, dtype=np.int64)
    for tile in np.argsort(-cost, kind="mergesort"):
        w = np.argmin(load)
        owner[tile] = w
        load[w] += cost[tile]
    order = np.argsort(owner, kind="mergesort")
    starts = np.zeros(workers + 1, dtype=np.int64)
    for tile in range(n_tiles):
        starts[owner[tile] + 1] += 1
    return order, np.cumsum(starts)


@_jit(parallel=False)
def _pixel_box(
    mx: float, my: float, a: float, b: float, c: float, opacity: float, box: Array
) -> bool:
    """Pixel range where the splat can reach alpha >= 1/255, clipped to ``box`` in place.

    ``box`` is ``[x0, x1, y0, y1]`` (inclusive) on entry and exit. Returns False when empty.
    """
    if opacity < ALPHA_MIN:
        return False
    det = a * c - b * b
    if not det > 0.0:
        return True  # degenerate conic: keep the whole tile, the alpha test decides
    q = 2.0 * math.log(opacity / ALPHA_MIN)
    rx = math.sqrt(q * c / det) + 1.0
    ry = math.sqrt(q * a / det) + 1.0
    box[0] = max(box[0], math.ceil(mx - rx))
    box[1] = min(box[1], math.floor(mx + rx))
    box[2] = max(box[2], math.ceil(my - ry))
    box[3] = min(box[3], math.floor(my + ry))
    return bool(box[0] <= box[1] and box[2] <= box[3])


@_jit(parallel=False)
def _tile_box(tile: int, tiles_x: int, width: int, height: int, box: Array) -> None:
    """Write the tile's inclusive pixel range ``[x0, x1, y0, y1]`` into ``box``."""
    box[0] = (tile % tiles_x) * TILE_SIZE
    box[1] = min(box[0] + TILE_SIZE, width) - 1
    box[2] = (tile // tiles_x) * TILE_SIZE
    box[3] = min(box[2] + TILE_SIZE, height) - 1


@_jit(parallel=False)
def _typed(values: Array, size: int) -> tuple[Array, Array]:
    """Pixel coordinates ``0..size-1`` and the constants (1/2, 1, ALPHA_MAX, ALPHA_MIN, T_MIN)
    in the dtype of ``values``."""
    coords = np.empty(size, dtype=values.dtype)
    for i in range(size):
        coords[i] = i
    consts = np.empty(5, dtype=values.dtype)
    consts[0], consts[1], consts[2], consts[3], consts[4] = 0.5, 1.0, ALPHA_MAX, ALPHA_MIN, T_MIN
    return coords, consts


@_jit(parallel=False)
def _sigma_cut(opacity: float) -> float:
    """A Mahalanobis half-distance beyond which ``opacity * exp(-sigma) < ALPHA_MIN`` for sure."""
    return math.log(opacity / ALPHA_MIN) + 1e-3


@_jit(parallel=True)
def forward(
    means2d: Array,
    conics: Array,
    opacities: Array,
    depths: Array,
    values: Array,
    index: Array,
    offsets: Array,
    ids: Array,
    width: int,
    height: int,
    tiles_x: int,
    order: Array,
    starts: Array,
) -> tuple[Array, Array, Array]:
    """Front-to-back alpha compositing; ``order`` and ``starts`` from :func:`balanced_tiles`.

    Splat ``g`` carries ``values[index[g]]`` (``values [N, C]`` per Gaussian) and ``depths[g]``.

    Returns:
        ``image [H, W, C + 2]`` (values, weighted depth, alpha), final transmittance ``[H, W]``
        and the number of tile-list entries up to and including each pixel's last contributor
        ``[H, W]`` int32.
    """
    out = np.zeros((height, width, values.shape[1] + 2), dtype=values.dtype)
    t_final = np.ones((height, width), dtype=values.dtype)
    n_contrib = np.zeros((height, width), dtype=np.int32)
    coords, consts = _typed(values, max(width, height))
    for worker in prange(starts.shape[0] - 1):
        for tile in order[starts[worker] : starts[worker + 1]]:
            _forward_tile(
                tile, means2d, conics, opacities, depths, values, index, offsets, ids, tiles_x,
                out, t_final, n_contrib, coords, consts,
            )  # fmt: skip
    return out, t_final, n_contrib


@_jit(parallel=False)
def _forward_tile(
    tile: int,
    means2d: Array,
    conics: Array,
    opacities: Array,
    depths: Array,
    values: Array,
    index: Array,
    offsets: Array,
    ids: Array,
    tiles_x: int,
    out: Array,
    t_final: Array,
    n_contrib: Array,
    coords: Array,
    consts: Array,
) -> None:
    height, width = out.shape[0], out.shape[1]
    tbox = np.empty(4, dtype=np.int64)
    _tile_box(tile, tiles_x, width, height, tbox)
    x0, y0 = tbox[0], tbox[2]
    n_pix = (tbox[1] - x0 + 1) * (tbox[3] - y0 + 1)
    trans = np.ones((TILE_SIZE, TILE_SIZE), dtype=values.dtype)
    done = np.zeros((TILE_SIZE, TILE_SIZE), dtype=np.bool_)
    last = np.zeros((TILE_SIZE, TILE_SIZE), dtype=np.int32)
    n_done = 0
    box = np.empty(4, dtype=np.int64)
    start = offsets[tile]
    for k in range(start, offsets[tile + 1]):
        g = ids[k]
        box[:] = tbox
        if _pixel_box(
            means2d[g, 0], means2d[g, 1], conics[g, 0], conics[g, 1], conics[g, 2],
            opacities[g], box,
        ):  # fmt: skip
            n_done += _forward_splat(
                k - start, g, box, x0, y0, means2d, conics, opacities, depths, values, index,
                out, trans, done, last, coords, consts,
            )  # fmt: skip
            if n_done == n_pix:
                break
    for i in range(tbox[3] - y0 + 1):
        for j in range(tbox[1] - x0 + 1):
            t_final[y0 + i, x0 + j] = trans[i, j]
            n_contrib[y0 + i, x0 + j] = last[i, j]


@_jit(parallel=False)
def _forward_splat(
    local: int,
    g: int,
    box: Array,
    x0: int,
    y0: int,
    means2d: Array,
    conics: Array,
    opacities: Array,
    depths: Array,
    values: Array,
    index: Array,
    out: Array,
    trans: Array,
    done: Array,
    last: Array,
    coords: Array,
    consts: Array,
) -> int:
    """Composite one splat over the pixels of ``box``; returns how many pixels it finished."""
    channels = values.shape[1]
    half, one, alpha_max, alpha_min, t_min = consts[0], consts[1], consts[2], consts[3], consts[4]
    mx, my = means2d[g, 0], means2d[g, 1]
    a, b, c = conics[g, 0], conics[g, 1], conics[g, 2]
    opacity, depth, source = opacities[g], depths[g], index[g]
    cut = _sigma_cut(opacity)
    finished = 0
    for py in range(box[2], box[3] + 1):
        dy = my - coords[py]
        for px in range(box[0], box[1] + 1):
            i, j = py - y0, px - x0
            if done[i, j]:
                continue
            dx = mx - coords[px]
            sigma = half * (a * dx * dx + c * dy * dy) + b * dx * dy
            if sigma > cut or sigma < 0.0:
                continue
            alpha = min(alpha_max, opacity * math.exp(-sigma))
            if alpha < alpha_min:
                continue
            next_t = trans[i, j] * (one - alpha)
            if next_t <= t_min:
                done[i, j] = True
                finished += 1
                continue
            weight = alpha * trans[i, j]
            for ch in range(channels):
                out[py, px, ch] += weight * values[source, ch]
            out[py, px, channels] += weight * depth
            out[py, px, channels + 1] += weight
            trans[i, j] = next_t
            last[i, j] = local + 1
    return finished


@_jit(parallel=True)
def backward(
    means2d: Array,
    conics: Array,
    opacities: Array,
    depths: Array,
    values: Array,
    index: Array,
    offsets: Array,
    ids: Array,
    t_final: Array,
    n_contrib: Array,
    grad_out: Array,
    tiles_x: int,
    order: Array,
    starts: Array,
) -> Array:
    """Gradients of ``sum(grad_out * image)`` per tile-list entry (tiles shared as in forward);
    ``grad_out`` is ``[H, W, C + 2]`` like the forward's image.

    Returns:
        ``[n_isect, 7 + C]``: d/d(mean x, mean y, conic a, b, c, opacity, values..., depth) for
        each (tile, splat) entry of ``ids``; the caller sums rows by splat id.
    """
    grads = np.zeros((ids.shape[0], 7 + values.shape[1]), dtype=values.dtype)
    coords, consts = _typed(values, max(grad_out.shape[0], grad_out.shape[1]))
    for worker in prange(starts.shape[0] - 1):
        for tile in order[starts[worker] : starts[worker + 1]]:
            _backward_tile(
                tile, means2d, conics, opacities, depths, values, index, offsets, ids, t_final,
                n_contrib, grad_out, tiles_x, grads, coords, consts,
            )  # fmt: skip
    return grads


@_jit(parallel=False)
def _backward_tile(
    tile: int,
    means2d: Array,
    conics: Array,
    opacities: Array,
    depths: Array,
    values: Array,
    index: Array,
    offsets: Array,
    ids: Array,
    t_final: Array,
    n_contrib: Array,
    grad_out: Array,
    tiles_x: int,
    grads: Array,
    coords: Array,
    consts: Array,
) -> None:
    height, width = grad_out.shape[0], grad_out.shape[1]
    tbox = np.empty(4, dtype=np.int64)
    _tile_box(tile, tiles_x, width, height, tbox)
    x0, y0 = tbox[0], tbox[2]
    trans = np.empty((TILE_SIZE, TILE_SIZE), dtype=values.dtype)
    later = np.zeros((TILE_SIZE, TILE_SIZE), dtype=values.dtype)  # sum_{k>j} w_k (v_k . g)
    last = np.zeros((TILE_SIZE, TILE_SIZE), dtype=np.int32)
    for i in range(tbox[3] - y0 + 1):
        for j in range(tbox[1] - x0 + 1):
            trans[i, j] = t_final[y0 + i, x0 + j]
            last[i, j] = n_contrib[y0 + i, x0 + j]
    box = np.empty(4, dtype=np.int64)
    start = offsets[tile]
    # entries past every pixel's last contributor cannot contribute: start from there
    for k in range(start + last.max() - 1, start - 1, -1):
        g = ids[k]
        box[:] = tbox
        if _pixel_box(
            means2d[g, 0], means2d[g, 1], conics[g, 0], conics[g, 1], conics[g, 2],
            opacities[g], box,
        ):  # fmt: skip
            _backward_splat(
                k - start, g, box, x0, y0, means2d, conics, opacities, depths, values, index,
                grad_out, trans, later, last, grads, k, coords, consts,
            )  # fmt: skip


@_jit(parallel=True)
def sum_by_splat(per_isect: Array, ids: Array, n_splats: int, parts: int) -> Array:
    """``[n_splats, K]`` sums of the rows of ``per_isect [n_isect, K]`` by splat id ``ids``.

    Each of ``parts`` threads owns a range of splat ids and adds their entries in list order,
    so the result is deterministic; ~2x faster than ``Tensor.index_add_`` on two cores.
    """
    sums = np.zeros((n_splats, per_isect.shape[1]), dtype=per_isect.dtype)
    for part in prange(parts):
        lo, hi = part * n_splats // parts, (part + 1) * n_splats // parts
        for k in range(ids.shape[0]):
            g = ids[k]
            if lo <= g < hi:
                for c in range(per_isect.shape[1]):
                    sums[g, c] += per_isect[k, c]
    return sums


@_jit(parallel=False)
def _dot(values: Array, g: int, grad_out: Array, py: int, px: int) -> float:
    """``values[g] . grad_out[py, px]`` with four independent partial sums.

    Takes whole arrays and indices: row views (``values[g]``) would update the shared arrays'
    reference counts atomically from every thread, millions of times per image.
    """
    n = values.shape[1]
    s0 = s1 = s2 = s3 = 0.0
    head = n - n % 4
    for k in range(0, head, 4):
        s0 += values[g, k] * grad_out[py, px, k]
        s1 += values[g, k + 1] * grad_out[py, px, k + 1]
        s2 += values[g, k + 2] * grad_out[py, px, k + 2]
        s3 += values[g, k + 3] * grad_out[py, px, k + 3]
    for k in range(head, n):
        s0 += values[g, k] * grad_out[py, px, k]
    return (s0 + s1) + (s2 + s3)


@_jit(parallel=False)
def _backward_splat(
    local: int,
    g: int,
    box: Array,
    x0: int,
    y0: int,
    means2d: Array,
    conics: Array,
    opacities: Array,
    depths: Array,
    values: Array,
    index: Array,
    grad_out: Array,
    trans: Array,
    later: Array,
    last: Array,
    grads: Array,
    row: int,
    coords: Array,
    consts: Array,
) -> None:
    """Accumulate one splat's gradients over the pixels of ``box`` into ``grads[row]``."""
    channels = values.shape[1]
    half, one, alpha_max, alpha_min = consts[0], consts[1], consts[2], consts[3]
    mx, my = means2d[g, 0], means2d[g, 1]
    a, b, c = conics[g, 0], conics[g, 1], conics[g, 2]
    opacity, depth, source = opacities[g], depths[g], index[g]
    cut = _sigma_cut(opacity)
    g_mx = g_my = g_a = g_b = g_c = g_o = 0.0  # local sums: no store per pixel
    for py in range(box[2], box[3] + 1):
        dy = my - coords[py]
        for px in range(box[0], box[1] + 1):
            i, j = py - y0, px - x0
            if local >= last[i, j]:
                continue
            dx = mx - coords[px]
            sigma = half * (a * dx * dx + c * dy * dy) + b * dx * dy
            if sigma > cut or sigma < 0.0:
                continue
            gauss = math.exp(-sigma)
            raw = opacity * gauss
            alpha = min(alpha_max, raw)
            if alpha < alpha_min:
                continue
            inv = one / (one - alpha)
            t_before = trans[i, j] * inv
            trans[i, j] = t_before
            weight = alpha * t_before
            v_dot_g = _dot(values, source, grad_out, py, px)
            v_dot_g += depth * grad_out[py, px, channels] + grad_out[py, px, channels + 1]
            for ch in range(channels + 1):  # the values, then the depth
                grads[row, 6 + ch] += weight * grad_out[py, px, ch]
            d_alpha = t_before * v_dot_g - later[i, j] * inv
            later[i, j] += weight * v_dot_g
            if raw > alpha_max:
                continue  # clamped: alpha does not depend on the splat here
            d_sigma = -raw * d_alpha
            g_mx += (a * dx + b * dy) * d_sigma
            g_my += (b * dx + c * dy) * d_sigma
            g_a += half * dx * dx * d_sigma
            g_b += dx * dy * d_sigma
            g_c += half * dy * dy * d_sigma
            g_o += gauss * d_alpha
    grads[row, 0], grads[row, 1], grads[row, 2] = g_mx, g_my, g_a
    grads[row, 3], grads[row, 4], grads[row, 5] = g_b, g_c, g_o
