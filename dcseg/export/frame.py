"""The coordinate frame of an export: world axes, up axis, units, and the turn into glTF's Y-up.

A run's world frame is the capture's: camera poses are camera-to-world with OpenCV camera axes
(x right, y down, z forward), lengths in metres. The world's up direction is not stored by
every capture layout, so it is estimated as the mean of the cameras' "up" (their -y axis,
``-c2w[:3, 1]``): people hold capture devices roughly level. An estimate within
:data:`SNAP_DEGREES` of a world axis is snapped to that axis. The rotation that takes this up
to +Y (glTF 2.0 and WebXR are Y-up, right-handed, metres) is applied to every GLB node, baked
into SPZ files (SPZ stores RUB, glTF's axes; :mod:`dcseg.export.axes`) and written, with the
rest, to ``frame.json``. PLY and .splat files keep world coordinates, as 3DGS tools expect.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

SNAP_DEGREES = 15.0
"""Snap an estimated up direction to the nearest world axis within this angle."""

_AXES = {"+x": (1, 0, 0), "-x": (-1, 0, 0), "+y": (0, 1, 0), "-y": (0, -1, 0), "+z": (0, 0, 1)}
_AXES["-z"] = (0, 0, -1)


def estimate_up(c2w: NDArray[np.float64]) -> NDArray[np.float64] | None:
    """Unit world up from ``[V, 4, 4]`` poses (mean camera -y), or None when they cancel."""
    mean = -np.asarray(c2w, np.float64)[:, :3, 1].mean(axis=0)
    norm = float(np.linalg.norm(mean))
    return None if norm < 1e-6 else mean / norm


def snap_axis(up: NDArray[np.float64]) -> str | None:
    """The world axis (``"+z"`` ...) within :data:`SNAP_DEGREES` of ``up``, else None."""
    for name, axis in _AXES.items():
        if float(np.dot(up, axis)) >= math.cos(math.radians(SNAP_DEGREES)):
            return name
    return None


def rotation_to_y_up(up: NDArray[np.float64]) -> NDArray[np.float64]:
    """``[4, 4]`` rotation taking unit ``up`` to +Y (the smallest such turn; Rodrigues)."""
    target = np.array([0.0, 1.0, 0.0])
    axis = np.cross(up, target)
    s, c = float(np.linalg.norm(axis)), float(np.dot(up, target))
    if s < 1e-9:  # already +Y, or -Y: half turn about x
        rot = np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    else:
        k = axis / s
        cross = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
        rot = np.eye(3) + s * cross + (1 - c) * cross @ cross
    out = np.eye(4)
    out[:3, :3] = np.where(np.abs(rot) < 1e-12, 0.0, rot)
    return out


def describe_frame(c2w: NDArray[np.float64] | None, applied_in: list[str]) -> dict[str, Any]:
    """The body of ``frame.json`` for a run with poses ``c2w`` (None = no poses known)."""
    estimate = None if c2w is None or len(c2w) == 0 else estimate_up(c2w)
    axis = None if estimate is None else snap_axis(estimate)
    if estimate is None:
        up: NDArray[np.float64] | None = None
    else:
        up = np.asarray(_AXES[axis], np.float64) if axis else estimate
    turn = np.eye(4) if up is None else rotation_to_y_up(up)
    return {
        "units": "metres",
        "world": {
            "cameras": "OpenCV axes (x right, y down, z forward); poses are camera-to-world",
            "handedness": "right",
            "up": _rounded(up),
            "up_axis": axis,
            "up_estimate": _rounded(estimate),
            "up_source": "none (no camera poses)"
            if estimate is None
            else f"mean camera -y axis over {len(c2w)} views",  # type: ignore[arg-type]
        },
        "to_gltf": {
            "convention": "glTF 2.0 / WebXR: +Y up, right-handed, metres",
            "matrix": turn.tolist(),
            "layout": "row-major 4x4; gltf_point = matrix @ [world_point, 1]",
            "applied_in": applied_in,
        },
        "gaussians": "PLY and .splat files keep world coordinates (no turn applied); SPZ files "
        "are turned by the matrix (positions, rotations and SH) into SPZ's RUB axes",
    }


def _rounded(vector: NDArray[np.float64] | None) -> list[float] | None:
    return None if vector is None else [round(float(v), 6) + 0.0 for v in vector]  # no -0.0
