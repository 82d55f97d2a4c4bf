"""Per-mask 3D scale (method doc Part A §1.5): how big is the thing a 2D mask covers?

The scale of a mask is ``|| (2 std X, 2 std Y, 2 std Z) ||_2`` over the camera-space points of its
pixels (unbiased std), after a 3x3 majority erosion (box sum >= 5, zero padding) that trims thin
borders. Rotation-invariant, so camera space is enough (no pose needed).

dcseg differences from SAGA's ``get_scale.py``: depth is the capture's metric depth (or a rendered
one where the capture has none) and pixels with invalid depth (0) are left out; the depth map is
resampled (nearest, intrinsics scaled) to the mask resolution instead of upsampling the masks to
the depth resolution; a mask with fewer than ``min_points`` valid points gets NaN (no scale).
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from dcseg.io.masks import decode_masks
from dcseg.types import AgnosticMasks

ERODE_MIN = 5
"""A pixel survives the erosion when at least this many of its 3x3 neighbours are in the mask."""


def mask_scales(
    masks: AgnosticMasks,
    depth: NDArray[np.float32],
    K: NDArray[np.float64],
    *,
    min_points: int = 10,
) -> NDArray[np.float32]:
    """The 3D scale of every mask of a frame.

    Args:
        masks: the frame's M class-agnostic masks at ``H_m x W_m``.
        depth: ``[H, W]`` metres, 0 = invalid; resampled (nearest) to the mask size if different.
        K: ``[3, 3]`` camera matrix for ``W x H``.
        min_points: masks with fewer valid eroded points get NaN.

    Returns:
        ``[M]`` float32 scales in the depth's unit (NaN = too few valid points).
    """
    points, valid = camera_points(depth, K, masks.height, masks.width)
    out = [scale_of_mask(m, points, valid, min_points) for m in decoded_masks(masks)]
    return np.asarray(out, dtype=np.float32)


def decoded_masks(masks: AgnosticMasks) -> Iterator[NDArray[np.bool_]]:
    """Decode the masks one at a time (``[H_m, W_m]`` bool each): never a dense stack."""
    for i in range(len(masks)):
        yield decode_masks(masks, [i])[0]


def camera_points(
    depth: NDArray[np.float32], K: NDArray[np.float64], height: int, width: int
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Back-project ``depth`` to camera space on a ``height x width`` pixel grid.

    Returns:
        ``[H, W, 3]`` camera-space XYZ (OpenCV axes) and ``[H, W]`` validity (depth > 0, finite).
    """
    z, k = _resampled(np.asarray(depth, dtype=np.float64), np.asarray(K), height, width)
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    x = (u - k[0, 2]) / k[0, 0] * z
    y = (v - k[1, 2]) / k[1, 1] * z
    valid = np.isfinite(z) & (z > 0)
    return np.stack([x, y, z], axis=-1), valid


def erode(mask: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """3x3 box sum >= 5 with zero padding (SAGA's majority erosion)."""
    rows, cols = np.flatnonzero(mask.any(1)), np.flatnonzero(mask.any(0))
    out = np.zeros_like(mask)
    if rows.size == 0:
        return out
    r0, r1 = max(rows[0] - 1, 0), min(rows[-1] + 2, mask.shape[0])
    c0, c1 = max(cols[0] - 1, 0), min(cols[-1] + 2, mask.shape[1])
    crop = mask[r0:r1, c0:c1].astype(np.uint8)
    box = ndimage.correlate(crop, np.ones((3, 3), np.uint8), mode="constant", cval=0)
    out[r0:r1, c0:c1] = box >= ERODE_MIN
    return out


def scale_of_mask(
    mask: NDArray[np.bool_],
    points: NDArray[np.float64],
    valid: NDArray[np.bool_],
    min_points: int,
) -> float:
    """``||2 std(XYZ)||`` of the eroded mask's valid points, NaN if fewer than ``min_points``."""
    keep = erode(mask) & valid
    if int(keep.sum()) < max(min_points, 2):
        return float("nan")
    std = points[keep].std(axis=0, ddof=1)
    return float(np.linalg.norm(2.0 * std))


def _resampled(
    depth: NDArray[np.float64], K: NDArray[Any], height: int, width: int
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Nearest-neighbour resample of depth to ``height x width`` with matching intrinsics."""
    h, w = depth.shape
    if (h, w) == (height, width):
        return depth, K.astype(np.float64)
    sy, sx = height / h, width / w
    rows = np.minimum(((np.arange(height) + 0.5) / sy).astype(np.int64), h - 1)
    cols = np.minimum(((np.arange(width) + 0.5) / sx).astype(np.int64), w - 1)
    k = K.astype(np.float64).copy()
    k[0, 0], k[1, 1] = k[0, 0] * sx, k[1, 1] * sy
    k[0, 2], k[1, 2] = (k[0, 2] + 0.5) * sx - 0.5, (k[1, 2] + 0.5) * sy - 0.5
    return depth[rows][:, cols], k
