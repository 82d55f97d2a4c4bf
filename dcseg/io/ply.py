"""Gaussians to and from the 3D Gaussian Splatting PLY layout.

One binary little-endian ``vertex`` element with float32 properties, in this order::

    x y z nx ny nz f_dc_0..2 f_rest_0..(3*(K-1)-1) opacity scale_0..2 rot_0..3

``opacity`` is the logit, ``scale_*`` are log scales, ``rot_*`` is the quaternion ``wxyz`` and
``f_rest`` is channel-major (all R coefficients, then G, then B), as written by the original
3DGS code, so viewers and tools for that format read our files. Extra integer columns (such as
``instance_id``) may follow; readers of the plain layout ignore them.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray
from plyfile import PlyData, PlyElement

from dcseg.errors import InputError
from dcseg.gaussians import Gaussians

_BASE = ("x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2")
_TAIL = ("opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3")


def _rest_names(coeffs: int) -> list[str]:
    return [f"f_rest_{i}" for i in range(3 * (coeffs - 1))]


def _float_columns(gaussians: Gaussians) -> dict[str, NDArray[np.float32]]:
    g = gaussians.detach().to("cpu")
    n, k = len(g), g.sh.shape[1]
    sh = g.sh.float().numpy()
    rest = sh[:, 1:, :].transpose(0, 2, 1).reshape(n, 3 * (k - 1))
    columns = [
        g.means.float().numpy(),
        np.zeros((n, 3), np.float32),
        sh[:, 0, :],
        rest,
        g.opacity_logits.float().numpy()[:, None],
        g.log_scales.float().numpy(),
        g.quats.float().numpy(),
    ]
    names = [*_BASE[:3], *_BASE[3:6], *_BASE[6:], *_rest_names(k), *_TAIL]
    stacked = np.concatenate(columns, axis=1).astype(np.float32)
    return {name: stacked[:, i] for i, name in enumerate(names)}


def _extra_column(name: str, values: NDArray[Any], n: int) -> NDArray[Any]:
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
    columns: dict[str, NDArray[Any]] = dict(_float_columns(gaussians))
    for name, values in (extra or {}).items():
        if name in columns:
            raise ValueError(f"extra column {name!r} clashes with a standard 3DGS property")
        columns[name] = _extra_column(name, values, len(gaussians))
    dtype = [(name, "<f4" if col.dtype == np.float32 else "<i4") for name, col in columns.items()]
    records = np.empty(len(gaussians), dtype=dtype)
    for name, col in columns.items():
        records[name] = col
    element = PlyElement.describe(records, "vertex")
    PlyData([element], text=False, byte_order="<").write(str(path))


def _sh_coeff_count(names: set[str], path: str) -> int:
    rest = sum(1 for name in names if name.startswith("f_rest_"))
    if rest % 3:
        raise InputError.single(path, f"f_rest_* count {rest} is not a multiple of 3")
    coeffs = rest // 3 + 1
    degree = round(coeffs**0.5) - 1
    if (degree + 1) ** 2 != coeffs:
        raise InputError.single(path, f"{rest} f_rest_* properties match no SH degree")
    return coeffs


def _read_vertex(path: str) -> NDArray[Any]:
    try:
        ply = PlyData.read(path)
    except FileNotFoundError:
        raise InputError.single(path, "file not found") from None
    except Exception as exc:  # plyfile raises several types for malformed headers
        raise InputError.single(path, f"not a readable PLY file ({exc})") from None
    if "vertex" not in [e.name for e in ply.elements]:
        raise InputError.single(path, "PLY file has no 'vertex' element")
    data: NDArray[Any] = ply["vertex"].data
    return data


def _required(coeffs: int) -> list[str]:
    return [*_BASE[:3], *_BASE[6:], *_rest_names(coeffs), *_TAIL]


def read_gaussians_ply(path: str | Path) -> Gaussians:
    """Read Gaussians from a 3DGS-layout PLY (ours or the original 3DGS code's).

    Unknown properties (normals, ``instance_id``, SAGA's ``mask`` ...) are ignored.

    Raises:
        InputError: the file is missing, unreadable, or lacks a required property (the message
            names the file and every missing property).
    """
    path = str(path)
    data = _read_vertex(path)
    names = set(data.dtype.names or ())
    coeffs = _sh_coeff_count(names, path)
    missing = [name for name in _required(coeffs) if name not in names]
    if missing:
        raise InputError.single(path, f"missing PLY vertex properties: {', '.join(missing)}")

    n = len(data)

    def cols(keys: list[str] | tuple[str, ...]) -> torch.Tensor:
        stacked = np.empty((n, len(keys)), dtype=np.float32)
        for i, key in enumerate(keys):
            stacked[:, i] = data[key]
        return torch.from_numpy(stacked)

    dc = cols(_BASE[6:]).reshape(n, 1, 3)
    rest = cols(_rest_names(coeffs)).reshape(n, 3, coeffs - 1).transpose(1, 2)
    return Gaussians(
        means=cols(_BASE[:3]),
        quats=cols(_TAIL[4:]),
        log_scales=cols(_TAIL[1:4]),
        opacity_logits=cols(_TAIL[:1]).reshape(n),
        sh=torch.cat([dc, rest], dim=1).contiguous(),
    )


def read_ply_extra(path: str | Path, name: str) -> NDArray[np.int64] | None:
    """An extra integer column of a Gaussians PLY as int64, or None when the file lacks it."""
    data = _read_vertex(str(path))
    if name not in (data.dtype.names or ()):
        return None
    return np.asarray(data[name], dtype=np.int64)
