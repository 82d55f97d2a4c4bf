"""Depth file helpers of :mod:`.common`: bounded ``.npy`` reads and depth registration."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dcseg.errors import InputError
from dcseg.io import images

__all__ = ["read_npy", "register_depth"]


def read_npy(path: Path, shown: str) -> NDArray[Any]:
    """A ``.npy`` depth array; refused above ``images.MAX_PIXELS`` values, charged to the
    pixel budget before it is copied into memory."""
    try:
        mapped = np.load(path, mmap_mode="r", allow_pickle=False)
    except FileNotFoundError:
        raise InputError.single(shown, "missing") from None
    except (OSError, ValueError, EOFError) as exc:
        raise InputError.single(shown, f"cannot read .npy depth ({exc})") from None
    if mapped.size > images.MAX_PIXELS:
        raise InputError.single(
            shown,
            f"depth array has {mapped.size:,} values, above the limit of {images.MAX_PIXELS:,}",
        )
    images.charge_pixels(int(mapped.size), shown)
    return np.array(mapped)


def register_depth(
    depth: NDArray[np.float32],
    depth_k: NDArray[np.float64],
    colour: tuple[float, float, float, float],
    size: tuple[int, int],
) -> NDArray[np.float32]:
    """Nearest-neighbour lookup of depth for each colour pixel through both camera matrices
    (``colour`` = the colour image's fx, fy, cx, cy)."""
    fx, fy, cx, cy = colour
    u = (np.arange(size[0]) - cx) / fx
    v = (np.arange(size[1]) - cy) / fy
    cols = np.rint(depth_k[0, 0] * u + depth_k[0, 2]).astype(np.int64)
    rows = np.rint(depth_k[1, 1] * v + depth_k[1, 2]).astype(np.int64)
    height, width = depth.shape
    ok_c, ok_r = (cols >= 0) & (cols < width), (rows >= 0) & (rows < height)
    out = depth[np.clip(rows, 0, height - 1)[:, None], np.clip(cols, 0, width - 1)[None, :]]
    out = np.where(ok_r[:, None] & ok_c[None, :], out, np.float32(0.0))
    return np.ascontiguousarray(out, dtype=np.float32)
