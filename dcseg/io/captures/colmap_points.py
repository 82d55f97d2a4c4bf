"""COLMAP's ``points3D`` (text or binary) as :class:`~dcseg.types.SparsePoints`.

An RGB-only COLMAP capture (no ``depth/``) initialises its Gaussians from these points, as 3DGS
does. Layouts follow COLMAP's reference reader (``scripts/python/read_write_model.py``):

* ``points3D.txt``: per line ``POINT3D_ID X Y Z R G B ERROR TRACK[]``, the track being
  ``IMAGE_ID POINT2D_IDX`` pairs (only its length is kept);
* ``points3D.bin``: ``uint64`` count, then per point ``uint64`` id, ``float64`` x y z,
  ``uint8`` r g b, ``float64`` error, ``uint64`` track length and per track element ``int32``
  image id, ``int32`` 2D point index (skipped), all little-endian.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from dcseg.errors import InputError
from dcseg.io.captures.binary import BinaryReader, open_binary
from dcseg.types import SparsePoints

__all__ = ["read_points3d"]

_Row = tuple[float, float, float, int, int, int, float, int]
_POINT_HEADER = 8 + 24 + 3 + 8 + 8  # id, xyz, rgb, error, track length


def read_points3d(path: Path, shown: str) -> SparsePoints:
    """Every point of a ``points3D.bin`` / ``.txt``, naming the line or point of a bad field.

    Raises:
        InputError: the file is unreadable, truncated, or a field is malformed (non-finite
            coordinates, a colour outside 0..255, a negative error or track length).
    """
    rows = _binary(path, shown) if path.suffix == ".bin" else _text(path, shown)
    table = np.array(rows, dtype=np.float64).reshape(-1, 8)
    return SparsePoints(
        xyz=np.ascontiguousarray(table[:, :3]),
        rgb=table[:, 3:6].astype(np.uint8),
        error=np.ascontiguousarray(table[:, 6]),
        track=table[:, 7].astype(np.int64),
        source=shown,
    )


def _text(path: Path, shown: str) -> list[_Row]:
    try:
        lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
    except OSError as exc:
        raise InputError.single(shown, f"cannot read file ({exc.strerror})") from None
    rows: list[_Row] = []
    for number, line in enumerate(lines, start=1):
        values = line.split()
        if not values or values[0].startswith("#"):
            continue
        where = f"{shown}:line {number}"
        if len(values) < 8 or (len(values) - 8) % 2:
            raise InputError.single(
                where,
                "expected POINT3D_ID X Y Z R G B ERROR then IMAGE_ID POINT2D_IDX pairs, got "
                f"{len(values)} values",
            )
        try:
            numbers = [float(v) for v in values[1:8]]
        except ValueError:
            raise InputError.single(where, f"X Y Z R G B ERROR must be numbers: {line}") from None
        x, y, z, r, g, b, error = numbers
        rows.append(
            _checked((x, y, z, int(r), int(g), int(b), error, (len(values) - 8) // 2), where)
        )
    return rows


def _binary(path: Path, shown: str) -> list[_Row]:
    handle, size = open_binary(path, shown)
    rows: list[_Row] = []
    with handle:
        data = BinaryReader(handle, size, shown)
        for k in range(data.count("point", _POINT_HEADER)):
            field = f"point {k + 1}"
            point_id, x, y, z, r, g, b, error = data.take("QdddBBBd", f"{field}: id/xyz/rgb/error")
            (track,) = data.take("Q", f"{field} (id {point_id}): track length")
            data.skip(8 * track, f"{field} (id {point_id}): {track} track elements")
            rows.append(_checked((x, y, z, r, g, b, error, track), f"{shown}:point {point_id}"))
    return rows


def _checked(row: _Row, where: str) -> _Row:
    x, y, z, r, g, b, error, track = row
    if not all(math.isfinite(v) for v in (x, y, z)):
        raise InputError.single(where, f"X Y Z must be finite, got {x} {y} {z}")
    if not all(0 <= c <= 255 for c in (r, g, b)):
        raise InputError.single(where, f"R G B must be in 0..255, got {r} {g} {b}")
    if not (math.isfinite(error) and error >= 0 or error == -1):
        raise InputError.single(where, f"ERROR must be >= 0 (or -1 = unknown), got {error}")
    return row
