"""Gaussians as numpy columns, read from and written to the 3DGS PLY layout without torch.

The layout is the one :mod:`dcseg.io.ply` documents (binary little-endian ``vertex`` element,
``x y z nx ny nz f_dc_0..2 f_rest_* opacity scale_0..2 rot_0..3``, then int32 columns such as
``instance_id``). :mod:`dcseg.io.ply` builds torch Gaussians on top of this module; exports and
the service use it directly, so they never import torch.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from plyfile import PlyData, PlyElement

from dcseg.errors import InputError
from dcseg.io.ply_file import open_ply

BASE = ("x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2")
TAIL = ("opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3")
SH_C0 = 0.28209479177387814
"""Zeroth spherical-harmonic basis constant: colour = 0.5 + SH_C0 * f_dc."""


def rest_names(coeffs: int) -> list[str]:
    """``f_rest_*`` names of ``coeffs`` SH coefficients per channel (the DC one excluded)."""
    return [f"f_rest_{i}" for i in range(3 * (coeffs - 1))]


@dataclass(frozen=True)
class SplatTable:
    """Gaussians in the PLY's own conventions, one row per Gaussian.

    Attributes:
        means: ``[N, 3]`` float32 centres.
        quats: ``[N, 4]`` float32 rotations ``wxyz`` (not necessarily normalised).
        log_scales: ``[N, 3]`` float32 log scales.
        opacity_logits: ``[N]`` float32 opacity logits.
        sh: ``[N, K, 3]`` float32 SH coefficients, DC first (K = (degree + 1)^2).
        ints: extra integer columns by name (``instance_id``, ``semantic_id`` ...), each ``[N]``.
    """

    means: NDArray[np.float32]
    quats: NDArray[np.float32]
    log_scales: NDArray[np.float32]
    opacity_logits: NDArray[np.float32]
    sh: NDArray[np.float32]
    ints: Mapping[str, NDArray[np.int32]] = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.means.shape[0])

    @property
    def sh_degree(self) -> int:
        return int(round(self.sh.shape[1] ** 0.5)) - 1

    def take(self, rows: NDArray[Any]) -> SplatTable:
        """The Gaussians at ``rows`` (a boolean mask or integer indices), in that order."""
        return SplatTable(
            means=self.means[rows],
            quats=self.quats[rows],
            log_scales=self.log_scales[rows],
            opacity_logits=self.opacity_logits[rows],
            sh=self.sh[rows],
            ints={name: values[rows] for name, values in self.ints.items()},
        )


def read_vertex(path: str) -> NDArray[Any]:
    """The ``vertex`` element of a PLY file as a structured array."""
    ply = open_ply(Path(path), path)
    if "vertex" not in [e.name for e in ply.elements]:
        raise InputError.single(path, "PLY file has no 'vertex' element")
    data: NDArray[Any] = ply["vertex"].data
    return data


def sh_coeff_count(names: set[str], path: str) -> int:
    """SH coefficients per channel implied by the ``f_rest_*`` properties present."""
    rest = sum(1 for name in names if name.startswith("f_rest_"))
    if rest % 3:
        raise InputError.single(path, f"f_rest_* count {rest} is not a multiple of 3")
    coeffs = rest // 3 + 1
    degree = round(coeffs**0.5) - 1
    if (degree + 1) ** 2 != coeffs:
        raise InputError.single(path, f"{rest} f_rest_* properties match no SH degree")
    return coeffs


def required_names(coeffs: int) -> list[str]:
    return [*BASE[:3], *BASE[6:], *rest_names(coeffs), *TAIL]


def read_splat_table(path: str | Path) -> SplatTable:
    """Read a 3DGS-layout PLY; integer properties are kept by name in :attr:`SplatTable.ints`.

    Raises:
        InputError: the file is missing, unreadable, or lacks a required property (the message
            names the file and every missing property).
    """
    path = str(path)
    data = read_vertex(path)
    names = set(data.dtype.names or ())
    coeffs = sh_coeff_count(names, path)
    missing = [name for name in required_names(coeffs) if name not in names]
    if missing:
        raise InputError.single(path, f"missing PLY vertex properties: {', '.join(missing)}")
    n = len(data)

    def cols(keys: list[str] | tuple[str, ...]) -> NDArray[np.float32]:
        stacked = np.empty((n, len(keys)), dtype=np.float32)
        for i, key in enumerate(keys):
            stacked[:, i] = data[key]
        return stacked

    dc = cols(BASE[6:]).reshape(n, 1, 3)
    rest = cols(rest_names(coeffs)).reshape(n, 3, coeffs - 1).transpose(0, 2, 1)
    ints = {
        name: np.asarray(data[name], dtype=np.int32)
        for name in data.dtype.names or ()
        if np.issubdtype(data.dtype[name], np.integer)
    }
    return SplatTable(
        means=cols(BASE[:3]),
        quats=cols(TAIL[4:]),
        log_scales=cols(TAIL[1:4]),
        opacity_logits=cols(TAIL[:1]).reshape(n),
        sh=np.ascontiguousarray(np.concatenate([dc, rest], axis=1)),
        ints=ints,
    )


def float_columns(table: SplatTable) -> dict[str, NDArray[np.float32]]:
    """The standard 3DGS float properties of ``table``, in file order."""
    n, k = len(table), table.sh.shape[1]
    rest = table.sh[:, 1:, :].transpose(0, 2, 1).reshape(n, 3 * (k - 1))
    columns = [
        table.means,
        np.zeros((n, 3), np.float32),
        table.sh[:, 0, :],
        rest,
        table.opacity_logits.reshape(n, 1),
        table.log_scales,
        table.quats,
    ]
    names = [*BASE, *rest_names(k), *TAIL]
    stacked = np.concatenate(columns, axis=1).astype(np.float32)
    return {name: stacked[:, i] for i, name in enumerate(names)}


def write_splat_table(path: str | Path, table: SplatTable) -> None:
    """Write ``table`` as a 3DGS-compatible binary PLY (integer columns as int32, last).

    Raises:
        ValueError: an integer column has the wrong shape or clashes with a standard property.
    """
    columns: dict[str, NDArray[Any]] = dict(float_columns(table))
    for name, values in table.ints.items():
        if name in columns:
            raise ValueError(f"extra column {name!r} clashes with a standard 3DGS property")
        if values.shape != (len(table),):
            raise ValueError(f"extra column {name!r} must have shape ({len(table)},)")
        columns[name] = values.astype(np.int32)
    dtype = [(name, "<f4" if col.dtype == np.float32 else "<i4") for name, col in columns.items()]
    records = np.empty(len(table), dtype=dtype)
    for name, col in columns.items():
        records[name] = col
    element = PlyElement.describe(records, "vertex")
    PlyData([element], text=False, byte_order="<").write(str(path))
