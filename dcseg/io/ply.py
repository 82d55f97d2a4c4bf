"""Gaussians to and from the 3D Gaussian Splatting PLY layout.

One binary little-endian ``vertex`` element with float32 properties, in this order::

    x y z nx ny nz f_dc_0..2 f_rest_0..(3*(K-1)-1) opacity scale_0..2 rot_0..3

``opacity`` is the logit, ``scale_*`` are log scales, ``rot_*`` is the quaternion ``wxyz`` and
``f_rest`` is channel-major (all R coefficients, then G, then B), as written by the original
3DGS code, so viewers and tools for that format read our files. Extra integer columns (such as
``instance_id``) may follow; readers of the plain layout ignore them. The numpy side (reading
and writing the columns) lives in :mod:`dcseg.io.splat_table`, which does not need torch.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray

from dcseg.gaussians import Gaussians
from dcseg.io.splat_table import SplatTable, read_splat_table, read_vertex, write_splat_table


def _table(gaussians: Gaussians, ints: dict[str, NDArray[np.int32]]) -> SplatTable:
    g = gaussians.detach().to("cpu")
    return SplatTable(
        means=g.means.float().numpy(),
        quats=g.quats.float().numpy(),
        log_scales=g.log_scales.float().numpy(),
        opacity_logits=g.opacity_logits.float().numpy(),
        sh=g.sh.float().numpy(),
        ints=ints,
    )


def _extra_column(name: str, values: NDArray[Any], n: int) -> NDArray[np.int32]:
    array = np.asarray(values)
    if array.shape != (n,):
        raise ValueError(f"extra column {name!r} must have shape ({n},), got {array.shape}")
    if not np.issubdtype(array.dtype, np.integer):
        raise ValueError(f"extra column {name!r} must be integer, got {array.dtype}")
    return array.astype(np.int32)


def write_gaussians_ply(
    path: str | Path, gaussians: Gaussians, extra: dict[str, NDArray[Any]] | None = None
) -> None:
    """Write Gaussians as a 3DGS-compatible binary PLY.

    Args:
        path: the file to write (parent folders must exist).
        gaussians: the Gaussians; tensors may live on any device and require grad.
        extra: additional per-Gaussian integer columns (e.g. ``instance_id``), each ``[N]``,
            stored as int32 after the standard properties.

    Raises:
        ValueError: an extra column has the wrong shape or dtype, or clashes with a standard one.
    """
    n = len(gaussians)
    ints = {name: _extra_column(name, values, n) for name, values in (extra or {}).items()}
    write_splat_table(path, _table(gaussians, ints))


def read_gaussians_ply(path: str | Path) -> Gaussians:
    """Read Gaussians from a 3DGS-layout PLY (ours or the original 3DGS code's).

    Unknown properties (normals, ``instance_id``, SAGA's ``mask`` ...) are ignored.

    Raises:
        InputError: the file is missing, unreadable, or lacks a required property (the message
            names the file and every missing property).
    """
    table = read_splat_table(path)
    return Gaussians(
        means=torch.from_numpy(table.means),
        quats=torch.from_numpy(table.quats),
        log_scales=torch.from_numpy(table.log_scales),
        opacity_logits=torch.from_numpy(table.opacity_logits),
        sh=torch.from_numpy(table.sh),
    )


def read_ply_extra(path: str | Path, name: str) -> NDArray[np.int64] | None:
    """An extra integer column of a Gaussians PLY as int64, or None when the file lacks it."""
    data = read_vertex(str(path))
    if name not in (data.dtype.names or ()):
        return None
    return np.asarray(data[name], dtype=np.int64)
