"""The ``cpu`` backend's depth planes: :func:`dcseg.render.planar.depth_planes` in numba kernels.

Same mathematics and results as the PyTorch function (which stays the other backends' path and
the test oracle), but one pass per Gaussian forward and one backward instead of ~40 whole-array
operations each way, which cost ``--surface-priors`` most of its extra time on the CPU. The
backward is the hand-derived chain rule of exactly those operations, with PyTorch's conventions
(``clamp`` passes the gradient inside its bounds, ``where`` only into the branch taken).
Arithmetic runs in float64; results are stored in the Gaussians' dtype. No gradients flow to
the camera (as with :mod:`dcseg.render.cpu_projection`).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import torch
from numba import prange
from torch import Tensor
from torch.autograd.function import once_differentiable

from dcseg.gaussians import Gaussians
from dcseg.render import numba_projection as npj
from dcseg.render.camera import Camera
from dcseg.render.cpu_projection import camera_arrays, to_numpy
from dcseg.render.numba_projection import CHUNK, GR, WORK_ROWS, Array, P, R, jit
from dcseg.render.planar import MAX_TILT

MIN_Z, MIN_C, MIN_SCALE = 1e-6, 1e-6, 1e-12
"""The floors of the PyTorch function: view depth, slope denominator, middle scale."""
NORM, G_MEAN, G_NORMAL, G_FLAT = P + 1, P + 2, P + 3, P + 4
"""Rows of the per-chunk scratch array (after ``P``, the camera-space mean): the quaternion's
norm, d/d(camera-space mean), d/d(camera-space normal), d/d(flatness); rows ``R`` hold the
rotation and ``GR`` its gradient, as in :mod:`dcseg.render.numba_projection`."""


def depth_planes_cpu(gaussians: Gaussians, camera: Camera) -> Tensor:
    """``[N, 3]`` ``(q0, a, b)`` per Gaussian, differentiable in means, quats and log scales."""
    out: Tensor = DepthPlanes.apply(  # type: ignore[no-untyped-call]
        gaussians.means, gaussians.quats, gaussians.log_scales, camera
    )
    return out


class DepthPlanes(torch.autograd.Function):
    """Differentiable depth planes of CPU Gaussians with the numba kernels below."""

    @staticmethod
    def forward(
        ctx: Any, means: Tensor, quats: Tensor, log_scales: Tensor, camera: Camera
    ) -> Tensor:
        view, intr = camera_arrays(camera, means.dtype)
        arrays = [to_numpy(t) for t in (means, quats, log_scales)]
        ctx.camera = (view, intr)
        ctx.save_for_backward(means, quats, log_scales)
        return torch.from_numpy(planes_forward(arrays[0], arrays[1], arrays[2], view, intr))

    @staticmethod
    @once_differentiable  # type: ignore[misc]
    def backward(ctx: Any, grad: Tensor) -> tuple[Tensor | None, ...]:
        view, intr = ctx.camera
        arrays = [to_numpy(t) for t in ctx.saved_tensors]
        out = planes_backward(
            arrays[0], arrays[1], arrays[2], view, intr, to_numpy(grad.to(torch.float64))
        )
        return (*(torch.from_numpy(a) for a in out), None)


@jit(parallel=False)
def _smallest_two(log_scales: Array, i: int) -> tuple[int, int]:
    """Axes of Gaussian ``i``'s smallest and middle scale (the first of equal ones first)."""
    lo, mid = 0, 1
    if log_scales[i, 1] < log_scales[i, 0]:
        lo, mid = 1, 0
    if log_scales[i, 2] < log_scales[i, lo]:
        lo, mid = 2, lo
    elif log_scales[i, 2] < log_scales[i, mid]:
        mid = 2
    return lo, mid


@jit(parallel=False)
def _turned(view: Array, work: Array, r: int, axis: int) -> float:
    """Row ``r`` of ``view[:3, :3] @ rotation[:, axis]`` (rotation in rows ``R`` of ``work``)."""
    return float(
        view[r, 0] * work[R, axis] + view[r, 1] * work[R + 1, axis] + view[r, 2] * work[R + 2, axis]
    )


@jit(parallel=False)
def _normal(
    quats: Array, log_scales: Array, i: int, view: Array, work: Array
) -> tuple[float, float, float, float, int, int]:
    """Gaussian ``i``'s shortest axis in the camera frame, its flatness, and the axes of its
    smallest and middle scale (rotation into rows ``R`` of ``work``)."""
    lo, mid = _smallest_two(log_scales, i)
    rotation_norm = npj.rotation(quats, i, work, R)
    n0, n1, n2 = _turned(view, work, 0, lo), _turned(view, work, 1, lo), _turned(view, work, 2, lo)
    s_lo, s_mid = math.exp(log_scales[i, lo]), max(math.exp(log_scales[i, mid]), MIN_SCALE)
    flat = min(max(1.0 - s_lo / s_mid, 0.0), 1.0)
    work[NORM, 0] = rotation_norm  # kept for the backward
    return n0, n1, n2, flat, lo, mid


@jit(parallel=True)
def planes_forward(
    means: Array, quats: Array, log_scales: Array, view: Array, intr: Array
) -> Array:
    """``[N, 3]`` ``(q0, a, b)`` in the dtype of ``means``."""
    n = means.shape[0]
    out = np.empty((n, 3), dtype=means.dtype)
    fx, fy = intr[0], intr[1]
    for chunk in prange((n + CHUNK - 1) // CHUNK):
        work = np.empty((WORK_ROWS, 3))
        for i in range(chunk * CHUNK, min(n, (chunk + 1) * CHUNK)):
            npj.camera_point(means, i, view, work)
            x, y, z = work[P, 0], work[P, 1], max(work[P, 2], MIN_Z)
            n0, n1, n2, flat, _, _ = _normal(quats, log_scales, i, view, work)
            c = (n0 * work[P, 0] + n1 * work[P, 1] + n2 * work[P, 2]) / z
            if abs(c) < MIN_C:
                c = MIN_C
            tu = min(max(n0 / c, -MAX_TILT), MAX_TILT) * flat
            tv = min(max(n1 / c, -MAX_TILT), MAX_TILT) * flat
            a, b = tu / (z * fx), tv / (z * fy)
            out[i, 0] = 1.0 / z - a * (fx * x / z) - b * (fy * y / z)
            out[i, 1], out[i, 2] = a, b
    return out


@jit(parallel=True)
def planes_backward(
    means: Array, quats: Array, log_scales: Array, view: Array, intr: Array, grad: Array
) -> tuple[Array, Array, Array]:
    """Gradients for means ``[N, 3]``, quats ``[N, 4]`` and log scales ``[N, 3]`` from the
    gradient ``[N, 3]`` of the planes (rows of zeros are skipped)."""
    n, dtype = means.shape[0], means.dtype
    g_means, g_quats = np.zeros((n, 3), dtype=dtype), np.zeros((n, 4), dtype=dtype)
    g_scales = np.zeros((n, 3), dtype=dtype)
    for chunk in prange((n + CHUNK - 1) // CHUNK):
        work = np.empty((WORK_ROWS, 3))
        for i in range(chunk * CHUNK, min(n, (chunk + 1) * CHUNK)):
            if grad[i, 0] == 0.0 and grad[i, 1] == 0.0 and grad[i, 2] == 0.0:
                continue
            _plane_grad(means, quats, log_scales, i, view, intr, grad, work)
            for c in range(3):
                g_means[i, c] = (
                    view[0, c] * work[G_MEAN, 0] + view[1, c] * work[G_MEAN, 1]
                    + view[2, c] * work[G_MEAN, 2]
                )  # fmt: skip
            _normal_grad(quats, log_scales, i, view, work, g_quats, g_scales)
    return g_means, g_quats, g_scales


@jit(parallel=False)
def _plane_grad(
    means: Array, quats: Array, log_scales: Array, i: int, view: Array, intr: Array,
    grad: Array, work: Array,
) -> None:  # fmt: skip
    """Fill the rows ``G_MEAN``, ``G_NORMAL`` and ``G_FLAT`` of ``work`` for Gaussian ``i``
    (rows ``R`` then hold its rotation, ``NORM`` its quaternion's norm)."""
    fx, fy = intr[0], intr[1]
    npj.camera_point(means, i, view, work)
    x, y, p2 = work[P, 0], work[P, 1], work[P, 2]
    z = max(p2, MIN_Z)
    n0, n1, n2, flat, _, _ = _normal(quats, log_scales, i, view, work)
    c_raw = (n0 * x + n1 * y + n2 * p2) / z
    c = MIN_C if abs(c_raw) < MIN_C else c_raw
    ru, rv = n0 / c, n1 / c
    cu, cv = min(max(ru, -MAX_TILT), MAX_TILT), min(max(rv, -MAX_TILT), MAX_TILT)
    tu, tv = cu * flat, cv * flat
    a, b = tu / (z * fx), tv / (z * fy)
    u0, v0 = fx * x / z, fy * y / z
    g_q, g_a, g_b = grad[i, 0], grad[i, 1] - grad[i, 0] * u0, grad[i, 2] - grad[i, 0] * v0
    g_x, g_y, g_z = -g_q * a * fx / z, -g_q * b * fy / z, -g_q / (z * z)
    g_z += g_q * (a * u0 + b * v0) / z - (g_a * a + g_b * b) / z
    g_tu, g_tv = g_a / (z * fx), g_b / (z * fy)
    work[G_FLAT, 0] = g_tu * cu + g_tv * cv  # d/d(flatness)
    g_ru = g_tu * flat if -MAX_TILT <= ru <= MAX_TILT else 0.0
    g_rv = g_tv * flat if -MAX_TILT <= rv <= MAX_TILT else 0.0
    work[G_NORMAL, 0], work[G_NORMAL, 1], work[G_NORMAL, 2] = g_ru / c, g_rv / c, 0.0
    g_p2 = 0.0
    if abs(c_raw) >= MIN_C:
        g_c = -(g_ru * n0 + g_rv * n1) / (c * c)
        for k, coordinate in ((0, x), (1, y), (2, p2)):
            work[G_NORMAL, k] += g_c * coordinate / z
        g_x, g_y, g_p2 = g_x + g_c * n0 / z, g_y + g_c * n1 / z, g_c * n2 / z
        g_z -= g_c * c_raw / z
    if p2 >= MIN_Z:
        g_p2 += g_z
    work[G_MEAN, 0], work[G_MEAN, 1], work[G_MEAN, 2] = g_x, g_y, g_p2


@jit(parallel=False)
def _normal_grad(
    quats: Array, log_scales: Array, i: int, view: Array, work: Array, g_quats: Array,
    g_scales: Array,
) -> None:  # fmt: skip
    """Rows ``g_quats[i]`` and ``g_scales[i]`` from d/d(normal) and d/d(flatness) in ``work``."""
    lo, mid = _smallest_two(log_scales, i)
    norm = work[NORM, 0]
    for r in range(3):
        for c in range(3):
            work[GR + r, c] = 0.0
        work[GR + r, lo] = (
            view[0, r] * work[G_NORMAL, 0]
            + view[1, r] * work[G_NORMAL, 1]
            + view[2, r] * work[G_NORMAL, 2]
        )
    npj.rotation_grad(quats, i, norm, work, g_quats)
    s_lo, s_mid_raw = math.exp(log_scales[i, lo]), math.exp(log_scales[i, mid])
    s_mid = max(s_mid_raw, MIN_SCALE)
    ratio = s_lo / s_mid
    if not 0.0 <= 1.0 - ratio <= 1.0:
        return
    g_flat = work[G_FLAT, 0]
    g_scales[i, lo] = -g_flat * ratio
    if s_mid_raw >= MIN_SCALE:
        g_scales[i, mid] = g_flat * ratio
