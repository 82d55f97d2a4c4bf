"""ARKit camera poses (Record3D, Polycam) in dcseg's OpenCV camera-to-world convention.

ARKit states a camera's pose as camera-to-world with the camera axes of OpenGL: x right, y up,
z backward (the camera looks down its -z axis). dcseg's cameras have OpenCV axes: x right,
y down, z forward. Both describe the same camera, so only the camera axes change:
``c2w_opencv = c2w_arkit @ diag(1, -1, -1, 1)`` (a half-turn about the camera's x axis). The
world frame is ARKit's, unchanged: gravity-aligned with y up, metres, origin where the session
started.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from dcseg.io.captures.nerfstudio import OPENGL_TO_OPENCV

__all__ = ["ARKIT_TO_OPENCV", "QUATERNION_TOLERANCE", "opencv_pose", "quaternion_pose"]

ARKIT_TO_OPENCV = OPENGL_TO_OPENCV
"""Right-multiply an ARKit (OpenGL-axes) camera-to-world pose by this to get OpenCV axes."""

QUATERNION_TOLERANCE = 1e-3
"""Largest accepted deviation of a pose quaternion's norm from 1."""


def opencv_pose(arkit_c2w: NDArray[np.float64]) -> NDArray[np.float64]:
    """An ARKit camera-to-world ``[4, 4]`` pose in OpenCV camera axes (same world frame)."""
    return np.asarray(arkit_c2w, dtype=np.float64) @ ARKIT_TO_OPENCV


def quaternion_pose(values: Sequence[float]) -> NDArray[np.float64] | str:
    """The ARKit camera-to-world pose ``[qx, qy, qz, qw, tx, ty, tz]`` as a ``[4, 4]`` matrix
    in ARKit axes, or the reason it is not a pose (a non-unit quaternion).

    The quaternion is scalar-last (Record3D's order) and rotates camera axes into the world.
    """
    qx, qy, qz, qw, tx, ty, tz = (float(v) for v in values)
    norm = math.sqrt(qx * qx + qy * qy + qz * qz + qw * qw)
    if abs(norm - 1.0) > QUATERNION_TOLERANCE:
        return f"quaternion (qx, qy, qz, qw) has norm {norm:.6g}, expected 1"
    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_quat([qx, qy, qz, qw]).as_matrix()
    pose[:3, 3] = (tx, ty, tz)
    return pose
