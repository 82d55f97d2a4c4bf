"""Truncated signed distance fusion of posed depth images (Curless & Levoy; KinectFusion's
running average), in numba on the CPU.

The grid spans the back-projected depth (a ``stride``-subsample of every view, 0.1-99.9th
percentiles, plus a truncation margin). Each voxel centre is projected into every view; where
the view sees a surface at depth ``d`` and the voxel is at camera depth ``z``, ``sdf = d - z``
is truncated to ``[-1, 1]`` in units of ``trunc`` and averaged over views. Voxels farther
than ``trunc`` behind every surface they project onto stay unobserved (weight 0): triangles
touching them are dropped after marching cubes (see :func:`observed_faces`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, TypeVar, cast

import numba
import numpy as np
from numba import prange
from numpy.typing import NDArray

from dcseg.errors import InputError
from dcseg.export.depth import DepthView

MAX_VOXELS = 64_000_000
"""Largest grid fused (8 bytes per voxel: 512 MB); a smaller voxel size is refused."""
TRUNC_VOXELS = 3.0
"""Truncation distance in voxels."""

_F = TypeVar("_F", bound=Callable[..., Any])
Array = Any  # numpy arrays; numba cannot see annotations


def _jit(parallel: bool) -> Callable[[_F], _F]:
    return cast(Callable[[_F], _F], numba.njit(parallel=parallel, cache=True, nogil=True))


@dataclass(frozen=True)
class Volume:
    """A fused grid.

    Attributes:
        tsdf: ``[X, Y, Z]`` float32 truncated distance in units of the truncation (1 = empty).
        weight: ``[X, Y, Z]`` float32 number of views that observed each voxel.
        origin: world position of voxel ``(0, 0, 0)``'s centre.
        voxel: voxel edge in metres.
    """

    tsdf: NDArray[np.float32]
    weight: NDArray[np.float32]
    origin: NDArray[np.float64]
    voxel: float

    def to_world(self, ijk: NDArray[Any]) -> NDArray[np.float64]:
        """World positions of fractional voxel coordinates ``[M, 3]``."""
        out: NDArray[np.float64] = self.origin + np.asarray(ijk, np.float64) * self.voxel
        return out


def depth_points(views: Sequence[DepthView], stride: int = 4) -> NDArray[np.float64]:
    """World points of every ``stride``-th valid depth pixel of every view."""
    out = []
    for view in views:
        depth = view.depth()
        v, u = np.mgrid[0 : depth.shape[0] : stride, 0 : depth.shape[1] : stride]
        z = depth[v, u].astype(np.float64)
        ok = z > 0
        K = view.K
        cam = np.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z], axis=-1)
        out.append(cam[ok] @ view.c2w[:3, :3].T + view.c2w[:3, 3])
    return np.concatenate(out) if out else np.zeros((0, 3))


def grid_for(
    views: Sequence[DepthView], voxel: float | None, per_side: int
) -> tuple[NDArray[np.float64], NDArray[np.int64], float]:
    """``(origin, shape, voxel)`` of a grid over the views' depth.

    Raises:
        InputError: no view has valid depth, or the grid would exceed :data:`MAX_VOXELS`.
    """
    points = depth_points(views)
    if len(points) == 0:
        raise InputError.single("depth", "no view has valid depth (all zero): nothing to mesh")
    lo, hi = np.percentile(points, 0.1, axis=0), np.percentile(points, 99.9, axis=0)
    size = float(np.max(hi - lo))
    voxel = voxel if voxel is not None else max(size, 1e-3) / per_side
    margin = 2 * TRUNC_VOXELS * voxel
    lo, hi = lo - margin, hi + margin
    shape = np.ceil((hi - lo) / voxel).astype(np.int64) + 1
    count = int(np.prod(shape))
    if count > MAX_VOXELS:
        reason = (
            f"a {voxel:.4g} m voxel needs {count:,} voxels over {np.round(hi - lo, 2).tolist()} m"
            f" (limit {MAX_VOXELS:,}); give a larger --voxel-size"
        )
        raise InputError.single("voxel_size", reason)
    return lo, shape, voxel


def fuse(views: Sequence[DepthView], voxel: float | None = None, per_side: int = 256) -> Volume:
    """Fuse ``views`` into a TSDF volume (voxel None = longest depth extent / ``per_side``)."""
    origin, shape, voxel = grid_for(views, voxel, per_side)
    tsdf = np.ones(tuple(shape), np.float32)
    weight = np.zeros(tuple(shape), np.float32)
    trunc = TRUNC_VOXELS * voxel
    for view in views:
        w2c = np.linalg.inv(view.c2w)
        depth = np.ascontiguousarray(view.depth(), dtype=np.float32)
        _integrate(tsdf, weight, origin, voxel, trunc, w2c, view.K.astype(np.float64), depth)
    return Volume(tsdf, weight, origin, voxel)


@_jit(parallel=True)
def _integrate(
    tsdf: Array,
    weight: Array,
    origin: Array,
    voxel: float,
    trunc: float,
    w2c: Array,
    K: Array,
    depth: Array,
) -> None:
    nx, ny, nz = tsdf.shape
    h, w = depth.shape
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    for i in prange(nx):
        px = origin[0] + i * voxel
        for j in range(ny):
            py = origin[1] + j * voxel
            for k in range(nz):
                pz = origin[2] + k * voxel
                z = w2c[2, 0] * px + w2c[2, 1] * py + w2c[2, 2] * pz + w2c[2, 3]
                if z <= 1e-6:
                    continue
                x = w2c[0, 0] * px + w2c[0, 1] * py + w2c[0, 2] * pz + w2c[0, 3]
                y = w2c[1, 0] * px + w2c[1, 1] * py + w2c[1, 2] * pz + w2c[1, 3]
                u = int(np.floor(fx * x / z + cx + 0.5))
                v = int(np.floor(fy * y / z + cy + 0.5))
                if u < 0 or v < 0 or u >= w or v >= h:
                    continue
                d = depth[v, u]
                if d <= 0.0:
                    continue
                sdf = d - z
                if sdf < -trunc:
                    continue
                value = min(1.0, sdf / trunc)
                old = weight[i, j, k]
                tsdf[i, j, k] = (tsdf[i, j, k] * old + value) / (old + 1.0)
                weight[i, j, k] = old + 1.0


def observed_faces(volume: Volume, vertices: NDArray[Any], faces: NDArray[Any]) -> NDArray[Any]:
    """The ``faces`` (over voxel-coordinate ``vertices``) whose cells every view-average saw:
    all 8 corners of each vertex's cell have weight > 0 (drops the spurious surfaces between
    observed and never-observed space)."""
    seen = volume.weight > 0
    shape = np.array(seen.shape) - 1
    cell = np.clip(np.floor(vertices).astype(np.int64), 0, shape - 1)
    ok = np.ones(len(vertices), bool)
    for dx in (0, 1):
        for dy in (0, 1):
            for dz in (0, 1):
                ok &= seen[cell[:, 0] + dx, cell[:, 1] + dy, cell[:, 2] + dz]
    keep: NDArray[Any] = faces[ok[faces].all(axis=1)]
    return keep
