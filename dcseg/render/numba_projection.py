"""numba kernels of the ``cpu`` backend's projection: EWA forward and its analytic backward.

The same mathematics as :mod:`dcseg.render.projection` (gsplat's ``fully_fused_projection``),
one Gaussian per ``prange`` iteration instead of ~200 whole-array PyTorch operations; the
backward is the hand-derived chain rule of exactly those operations (including PyTorch's
``clamp`` convention: the gradient passes where ``lo <= x / z <= hi``). Arithmetic runs in
float64 whatever the array dtype; results are stored in the arrays' dtype.

Camera arguments: ``view`` is the ``[4, 4]`` world-to-camera matrix and ``intr`` the tuple-like
``[fx, fy, cx, cy, width, height]`` (float64).

Private module; arrays are float32 or float64 (one compiled specialisation each).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, TypeVar, cast

import numba
import numpy as np
from numba import prange

from dcseg.render.projection import ALPHA_MIN, EPS2D, MAX_EXTEND, TILE_SIZE

CHUNK = 1024
"""Gaussians per parallel work item (each item allocates its scratch rows once)."""
WORK_ROWS = 24
"""Rows of the ``[24, 3]`` float64 per-chunk scratch array; the row of each quantity below.

Helpers index the shared arrays and the scratch rows directly: taking row views
(``means[i]``) would update the arrays' reference counts atomically from every thread.
"""
P, JW, M, A, GA, GJW, GM, GP, GJ, R, GR = 0, 1, 3, 6, 8, 10, 12, 15, 16, 18, 21

_F = TypeVar("_F", bound=Callable[..., Any])
Array = Any  # numpy arrays; numba cannot see annotations, mypy cannot see numba


def jit(parallel: bool) -> Callable[[_F], _F]:
    return cast(
        Callable[[_F], _F],
        numba.njit(parallel=parallel, cache=True, nogil=True, error_model="numpy"),
    )


@jit(parallel=False)
def rotation(quats: Array, i: int, work: Array, row: int) -> float:
    """Write the rotation of quaternion ``quats[i]`` (wxyz, any norm) into ``work[row:row+3]``.

    Returns the quaternion's norm (at least 1e-12, as ``F.normalize``).
    """
    q0, q1, q2, q3 = quats[i, 0], quats[i, 1], quats[i, 2], quats[i, 3]
    norm = max(math.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3), 1e-12)
    w, x, y, z = q0 / norm, q1 / norm, q2 / norm, q3 / norm
    work[row, 0] = 1 - 2 * (y * y + z * z)
    work[row, 1] = 2 * (x * y - w * z)
    work[row, 2] = 2 * (x * z + w * y)
    work[row + 1, 0] = 2 * (x * y + w * z)
    work[row + 1, 1] = 1 - 2 * (x * x + z * z)
    work[row + 1, 2] = 2 * (y * z - w * x)
    work[row + 2, 0] = 2 * (x * z - w * y)
    work[row + 2, 1] = 2 * (y * z + w * x)
    work[row + 2, 2] = 1 - 2 * (x * x + y * y)
    return norm


@jit(parallel=False)
def _clamp_bounds(intr: Array) -> tuple[float, float, float, float]:
    """gsplat's view-direction clamp ``(lo_x, hi_x, lo_y, hi_y)`` on ``x / z`` and ``y / z``."""
    fx, fy, cx, cy, width, height = intr[0], intr[1], intr[2], intr[3], intr[4], intr[5]
    tan_x, tan_y = 0.5 * width / fx, 0.5 * height / fy
    gx, gy = cx + 0.5, cy + 0.5
    return (
        -(gx / fx + 0.3 * tan_x),
        (width - gx) / fx + 0.3 * tan_x,
        -(gy / fy + 0.3 * tan_y),
        (height - gy) / fy + 0.3 * tan_y,
    )


@jit(parallel=False)
def camera_point(means: Array, i: int, view: Array, work: Array) -> float:
    """Fill row ``P`` with Gaussian ``i``'s camera-space mean; return its depth z."""
    for r in range(3):
        work[P, r] = view[r, 3]
        for c in range(3):
            work[P, r] += view[r, c] * means[i, c]
    return float(work[P, 2])


@jit(parallel=False)
def _splat_matrices(
    quats: Array, log_scales: Array, i: int, view: Array, intr: Array, work: Array
) -> None:
    """Fill the rows ``JW = J W [2, 3]``, ``M = R S [3, 3]`` and ``A = J W R S [2, 3]`` of
    ``work`` for Gaussian ``i`` (row ``P`` must hold its camera-space mean)."""
    fx, fy = intr[0], intr[1]
    lo_x, hi_x, lo_y, hi_y = _clamp_bounds(intr)
    x, y, z = work[P, 0], work[P, 1], work[P, 2]
    tx = z * min(max(x / z, lo_x), hi_x)
    ty = z * min(max(y / z, lo_y), hi_y)
    j00, j02 = fx / z, -fx * tx / (z * z)
    j11, j12 = fy / z, -fy * ty / (z * z)
    for k in range(3):
        work[JW, k] = j00 * view[0, k] + j02 * view[2, k]
        work[JW + 1, k] = j11 * view[1, k] + j12 * view[2, k]
    rotation(quats, i, work, M)
    for c in range(3):
        s = math.exp(log_scales[i, c])
        for r in range(3):
            work[M + r, c] *= s
    for r in range(2):
        for c in range(3):
            work[A + r, c] = (
                work[JW + r, 0] * work[M, c]
                + work[JW + r, 1] * work[M + 1, c]
                + work[JW + r, 2] * work[M + 2, c]
            )


@jit(parallel=False)
def _covariance(work: Array) -> tuple[float, float, float]:
    """The dilated 2D covariance ``(sxx, sxy, syy)`` = ``A A^T + EPS2D I`` from row ``A``."""
    sxx, sxy, syy = EPS2D, 0.0, EPS2D
    for c in range(3):
        sxx += work[A, c] * work[A, c]
        sxy += work[A, c] * work[A + 1, c]
        syy += work[A + 1, c] * work[A + 1, c]
    return sxx, sxy, syy


@jit(parallel=True)
def project_all(
    means: Array,
    quats: Array,
    log_scales: Array,
    logits: Array,
    view: Array,
    intr: Array,
    near: float,
) -> tuple[Array, Array, Array, Array, Array, Array]:
    """Project every Gaussian; ``near`` is :data:`NEAR_PLANE` rounded to the input precision
    (so that float32 inputs are culled exactly as the PyTorch projection culls them).

    Returns:
        ``depths [N]``, ``means2d [N, 2]``, ``conics [N, 3]``, ``opacities [N]``, ``radii [N, 2]``
        (float64) and ``visible [N]`` (bool: in front of the near plane, finite, non-degenerate,
        on screen, with a nonzero radius).
    """
    n = means.shape[0]
    depths, opac = np.zeros(n), np.zeros(n)
    means2d, conics, radii = np.zeros((n, 2)), np.zeros((n, 3)), np.zeros((n, 2))
    visible = np.zeros(n, dtype=np.bool_)
    for chunk in prange((n + CHUNK - 1) // CHUNK):
        work = np.empty((WORK_ROWS, 3))
        for i in range(chunk * CHUNK, min(n, (chunk + 1) * CHUNK)):
            z = camera_point(means, i, view, work)
            depths[i] = z
            if not z >= near:  # culled (also NaN): skip the covariance
                continue
            _splat_matrices(quats, log_scales, i, view, intr, work)
            means2d[i, 0] = intr[0] * work[P, 0] / z + intr[2]
            means2d[i, 1] = intr[1] * work[P, 1] / z + intr[3]
            sxx, sxy, syy = _covariance(work)
            det = sxx * syy - sxy * sxy
            conics[i, 0], conics[i, 1], conics[i, 2] = syy / det, -sxy / det, sxx / det
            opac[i] = 1.0 / (1.0 + math.exp(-logits[i]))
            visible[i] = _visible(opac[i], sxx, syy, det, means2d, i, intr, radii)
    return depths, means2d, conics, opac, radii, visible


@jit(parallel=False)
def _visible(
    o: float,
    sxx: float,
    syy: float,
    det: float,
    means2d: Array,
    i: int,
    intr: Array,
    radii: Array,
) -> bool:
    """Write gsplat's opacity-aware radii of splat ``i`` (in front of the near plane); return
    whether it is visible."""
    if o < ALPHA_MIN:
        return False
    extend = min(math.sqrt(2.0 * math.log(o / ALPHA_MIN)), MAX_EXTEND)
    rx = np.ceil(extend * math.sqrt(max(sxx, 0.0)))  # float: math.ceil is int64 in numba
    ry = np.ceil(extend * math.sqrt(max(syy, 0.0)))
    radii[i, 0], radii[i, 1] = rx, ry
    u, v = means2d[i, 0], means2d[i, 1]
    finite = math.isfinite(u) and math.isfinite(v) and math.isfinite(rx) and math.isfinite(ry)
    u, v = u + 0.5, v + 0.5  # gsplat pixel coordinates
    on_screen = u + rx > 0 and v + ry > 0 and u - rx < intr[4] and v - ry < intr[5]
    nonzero = rx > 0 or ry > 0
    return bool(finite and det > 0.0 and on_screen and nonzero)


@jit(parallel=False)
def radix_argsort(keys: Array) -> Array:
    """Stable argsort of unsigned integer ``keys`` (uint32 or uint64): LSD radix sort by bytes.

    Passes whose byte is the same for every key are skipped. For non-negative floats the bit
    patterns sort like the values, so this is ``np.argsort(values, kind="stable")`` in ~1/5 of
    the time (58k keys: ~1 ms instead of ~5 ms).
    """
    n = keys.shape[0]
    order, spare = np.arange(n), np.empty(n, dtype=np.int64)
    current, other = keys.copy(), np.empty_like(keys)
    for byte in range(keys.itemsize):
        shift = np.uint64(8 * byte)  # unsigned: numba promotes mixed signedness to float
        counts = np.zeros(257, dtype=np.int64)
        for i in range(n):
            counts[np.int64((current[i] >> shift) & np.uint64(255)) + 1] += 1
        if counts.max() == n:
            continue  # every key has this byte: the pass would not move anything
        starts = np.cumsum(counts)
        for i in range(n):
            bucket = np.int64((current[i] >> shift) & np.uint64(255))
            slot = starts[bucket]
            starts[bucket] += 1
            other[slot], spare[slot] = current[i], order[i]
        current, other = other, current
        order, spare = spare, order
    return order


@jit(parallel=True)
def gather_splats(
    index: Array,
    like: Array,
    means2d: Array,
    conics: Array,
    opacities: Array,
    depths: Array,
    radii: Array,
    tiles_x: int,
    tiles_y: int,
) -> tuple[Array, Array, Array, Array, Array, Array]:
    """The rows ``index`` of the projection's outputs in the dtype of ``like``, plus each splat's
    first and one-past-last tile (x, y) ``[M, 2]`` int64 of its bounding box (one fused pass)."""
    m = index.shape[0]
    out_means = np.empty((m, 2), dtype=like.dtype)
    out_conics = np.empty((m, 3), dtype=like.dtype)
    out_opac, out_depths = np.empty(m, dtype=like.dtype), np.empty(m, dtype=like.dtype)
    lo, hi = np.empty((m, 2), dtype=np.int64), np.empty((m, 2), dtype=np.int64)
    for k in prange(m):
        i = index[k]
        for c in range(3):
            out_conics[k, c] = conics[i, c]
        out_opac[k], out_depths[k] = opacities[i], depths[i]
        for d in range(2):
            out_means[k, d] = means2d[i, d]
            limit = tiles_x if d == 0 else tiles_y
            centre = (means2d[i, d] + 0.5) / TILE_SIZE
            half = radii[i, d] / TILE_SIZE
            lo[k, d] = min(max(math.floor(centre - half), 0), limit)
            hi[k, d] = min(max(math.ceil(centre + half), 0), limit)
    return out_means, out_conics, out_opac, out_depths, lo, hi


@jit(parallel=True)
def project_backward(
    index: Array,
    means: Array,
    quats: Array,
    log_scales: Array,
    logits: Array,
    view: Array,
    intr: Array,
    grad_means2d: Array,
    grad_conics: Array,
    grad_opac: Array,
    grad_depths: Array,
) -> tuple[Array, Array, Array, Array]:
    """Gradients for means ``[N, 3]``, quats ``[N, 4]``, log scales ``[N, 3]`` and logits ``[N]``
    in the dtype of ``means``.

    ``index [M]`` lists the projected Gaussians (distinct), the ``grad_*`` arrays are the
    gradients of their outputs in that order; Gaussians not in ``index`` get zeros.
    """
    n, m, dtype = means.shape[0], index.shape[0], means.dtype
    g_means, g_quats = np.zeros((n, 3), dtype=dtype), np.zeros((n, 4), dtype=dtype)
    g_scales, g_logits = np.zeros((n, 3), dtype=dtype), np.zeros(n, dtype=dtype)
    for chunk in prange((m + CHUNK - 1) // CHUNK):
        work = np.empty((WORK_ROWS, 3))
        for k in range(chunk * CHUNK, min(m, (chunk + 1) * CHUNK)):
            i = index[k]
            camera_point(means, i, view, work)
            _splat_matrices(quats, log_scales, i, view, intr, work)
            _covariance_grad(work, grad_conics, k)
            _jacobian_grad(work, view, intr, grad_means2d, k)
            work[GP, 2] += grad_depths[k]
            for c in range(3):
                g_means[i, c] = (
                    view[0, c] * work[GP, 0] + view[1, c] * work[GP, 1] + view[2, c] * work[GP, 2]
                )
            _rotation_scale_grad(quats, log_scales, i, work, g_quats, g_scales)
            o = 1.0 / (1.0 + math.exp(-logits[i]))
            g_logits[i] = grad_opac[k] * o * (1.0 - o)
    return g_means, g_quats, g_scales, g_logits


@jit(parallel=False)
def _covariance_grad(work: Array, grad_conics: Array, k: int) -> None:
    """Fill rows ``GA`` (d/dA), ``GJW`` (d/d(J W)) and ``GM`` (d/d(R S)) from splat ``k``'s
    conic gradient."""
    sxx, sxy, syy = _covariance(work)
    det = sxx * syy - sxy * sxy
    inv, inv2 = 1.0 / det, 1.0 / (det * det)
    ga, gb, gc = grad_conics[k, 0], grad_conics[k, 1], grad_conics[k, 2]
    # conic = (syy, -sxy, sxx) / det
    g_xx = ga * (-syy * syy * inv2) + gb * (sxy * syy * inv2) + gc * (inv - sxx * syy * inv2)
    g_xy = ga * (2 * sxy * syy * inv2) + gb * (-inv - 2 * sxy * sxy * inv2)
    g_xy += gc * (2 * sxx * sxy * inv2)
    g_yy = ga * (inv - sxx * syy * inv2) + gb * (sxy * sxx * inv2) + gc * (-sxx * sxx * inv2)
    for c in range(3):
        work[GA, c] = 2.0 * g_xx * work[A, c] + g_xy * work[A + 1, c]
        work[GA + 1, c] = g_xy * work[A, c] + 2.0 * g_yy * work[A + 1, c]
    for r in range(3):
        for c in range(3):
            if r < 2:
                work[GJW + r, c] = 0.0
            work[GM + r, c] = 0.0
    for r in range(2):
        for k2 in range(3):
            for c in range(3):
                work[GJW + r, k2] += work[GA + r, c] * work[M + k2, c]
                work[GM + k2, c] += work[JW + r, k2] * work[GA + r, c]


@jit(parallel=False)
def _jacobian_grad(work: Array, view: Array, intr: Array, grad_means2d: Array, k: int) -> None:
    """Fill row ``GP``: d/d(camera-space mean) through ``J`` (with its clamp) and the projected
    mean of splat ``k``; row ``GJ`` is scratch."""
    fx, fy = intr[0], intr[1]
    lo_x, hi_x, lo_y, hi_y = _clamp_bounds(intr)
    x, y, z = work[P, 0], work[P, 1], work[P, 2]
    for r in range(2):  # GJ = GJW @ W^T
        for col in range(3):
            work[GJ + r, col] = (
                work[GJW + r, 0] * view[col, 0]
                + work[GJW + r, 1] * view[col, 1]
                + work[GJW + r, 2] * view[col, 2]
            )
    gu, gv = grad_means2d[k, 0], grad_means2d[k, 1]
    work[GP, 0] = gu * fx / z
    work[GP, 1] = gv * fy / z
    work[GP, 2] = -(gu * fx * x + gv * fy * y) / (z * z)
    work[GP, 2] -= (work[GJ, 0] * fx + work[GJ + 1, 1] * fy) / (z * z)
    for axis, f, lo, hi in ((0, fx, lo_x, hi_x), (1, fy, lo_y, hi_y)):
        ratio = work[P, axis] / z
        clamped = min(max(ratio, lo), hi)
        g_j2 = work[GJ + axis, 2]
        g_t = g_j2 * (-f / (z * z))
        work[GP, 2] += g_j2 * 2.0 * f * z * clamped / (z * z * z) + g_t * clamped
        if lo <= ratio <= hi:  # torch.clamp passes the gradient inside [lo, hi]
            work[GP, axis] += g_t
            work[GP, 2] -= g_t * z * work[P, axis] / (z * z)


@jit(parallel=False)
def _rotation_scale_grad(
    quats: Array, log_scales: Array, i: int, work: Array, g_quats: Array, g_scales: Array
) -> None:
    """Rows ``g_quats[i]`` and ``g_scales[i]`` from row ``GM`` (d/d(R S)); rows ``R`` and
    ``GR`` are scratch."""
    norm = rotation(quats, i, work, R)
    for c in range(3):
        s = math.exp(log_scales[i, c])
        g_s = 0.0
        for row in range(3):
            work[GR + row, c] = work[GM + row, c] * s
            g_s += work[GM + row, c] * work[R + row, c]
        g_scales[i, c] = g_s * s
    rotation_grad(quats, i, norm, work, g_quats)


@jit(parallel=False)
def rotation_grad(quats: Array, i: int, norm: float, work: Array, g_quats: Array) -> None:
    """Row ``g_quats[i]`` from rows ``GR`` (d/d(rotation matrix) of quaternion ``quats[i]``,
    whose norm :func:`rotation` returned), through the normalisation."""
    w, x, y, z = (quats[i, 0] / norm, quats[i, 1] / norm, quats[i, 2] / norm, quats[i, 3] / norm)
    g00, g01, g02 = work[GR, 0], work[GR, 1], work[GR, 2]
    g10, g11, g12 = work[GR + 1, 0], work[GR + 1, 1], work[GR + 1, 2]
    g20, g21, g22 = work[GR + 2, 0], work[GR + 2, 1], work[GR + 2, 2]
    gw = 2 * (-z * g01 + y * g02 + z * g10 - x * g12 - y * g20 + x * g21)
    gx = 2 * (y * (g01 + g10) + z * (g02 + g20) + w * (g21 - g12) - 2 * x * (g11 + g22))
    gy = 2 * (x * (g01 + g10) + z * (g12 + g21) + w * (g02 - g20) - 2 * y * (g00 + g22))
    gz = 2 * (x * (g02 + g20) + y * (g12 + g21) + w * (g10 - g01) - 2 * z * (g00 + g11))
    dot = w * gw + x * gx + y * gy + z * gz
    g_quats[i, 0] = (gw - w * dot) / norm
    g_quats[i, 1] = (gx - x * dot) / norm
    g_quats[i, 2] = (gy - y * dot) / norm
    g_quats[i, 3] = (gz - z * dot) / norm
