"""A tiny ARKit-posed scene of walls at known places, shared by the Record3D and Polycam tests.

ARKit world: y up. Camera axes: x right, y up, z backward (looks down -z). Every camera faces
a wall square-on, so its depth is one constant and back-projected points must lie on the wall.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from dcseg.reconstruct.init import backproject
from dcseg.types import Capture, Frame

WIDTH, HEIGHT = 24, 18
"""Colour size."""
DEPTH_WIDTH, DEPTH_HEIGHT = 12, 9
"""Depth and confidence size (half the colour's, as the LiDAR's is smaller)."""
FX, FY, CX, CY = 20.0, 21.0, 11.5, 8.5

_S = math.sin(math.pi / 4)


@dataclass(frozen=True)
class View:
    quaternion: tuple[float, float, float, float]  # qx, qy, qz, qw (scalar last)
    translation: tuple[float, float, float]
    depth: float  # distance to the wall it faces
    wall_axis: int  # world axis the wall is perpendicular to
    wall_at: float  # the wall's coordinate on that axis
    look: tuple[float, float, float]  # world direction the camera looks along


VIEWS = (
    # identity rotation: looks down world -z at the wall z = -2
    View((0.0, 0.0, 0.0, 1.0), (0.3, 0.1, 0.5), 2.5, 2, -2.0, (0.0, 0.0, -1.0)),
    # +90 degrees about world y: looks down world -x at the wall x = -2
    View((0.0, _S, 0.0, _S), (0.0, 0.0, 0.0), 2.0, 0, -2.0, (-1.0, 0.0, 0.0)),
    View((0.0, 0.0, 0.0, 1.0), (0.0, 0.0, 0.0), 2.0, 2, -2.0, (0.0, 0.0, -1.0)),
)


def arkit_matrix(view: View) -> NDArray[np.float64]:
    """The view's ARKit camera-to-world pose (computed independently of the reader)."""
    qx, qy, qz, qw = view.quaternion
    rotation = np.array(
        [
            [1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qz * qw), 2 * (qx * qz + qy * qw)],
            [2 * (qx * qy + qz * qw), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qx * qw)],
            [2 * (qx * qz - qy * qw), 2 * (qy * qz + qx * qw), 1 - 2 * (qx * qx + qy * qy)],
        ]
    )
    pose = np.eye(4)
    pose[:3, :3] = rotation
    pose[:3, 3] = view.translation
    return pose


def colour(index: int) -> NDArray[np.uint8]:
    rng = np.random.default_rng(index)
    return rng.integers(0, 256, (HEIGHT, WIDTH, 3), dtype=np.uint8)


def depth_map(view: View) -> NDArray[np.float32]:
    """Metres at the depth resolution; the top-left pixel has no depth."""
    depth = np.full((DEPTH_HEIGHT, DEPTH_WIDTH), view.depth, dtype=np.float32)
    depth[0, 0] = 0.0
    return depth


def confidence_map() -> NDArray[np.uint8]:
    """ARKit levels by depth row: 0, 1, 2, 0, 1, 2, ..."""
    rows = (np.arange(DEPTH_HEIGHT) % 3).astype(np.uint8)
    return np.repeat(rows[:, None], DEPTH_WIDTH, axis=1)


def assert_views_read(capture: Capture) -> None:
    """Intrinsics, OpenCV poses and back-projected walls of a capture of :data:`VIEWS`."""
    assert len(capture) == len(VIEWS)
    for frame, view in zip(capture.frames, VIEWS, strict=True):
        k = frame.intrinsics
        assert (k.fx, k.fy, k.cx, k.cy, k.width, k.height) == (FX, FY, CX, CY, WIDTH, HEIGHT)
        assert frame.depth.shape == (HEIGHT, WIDTH)  # resampled onto the colour grid
        arkit = arkit_matrix(view)
        # same camera centre; OpenCV +z (forward) is ARKit's -z, OpenCV +y (down) is ARKit's -y
        np.testing.assert_allclose(frame.c2w[:3, 3], view.translation, atol=1e-12)
        np.testing.assert_allclose(frame.c2w[:3, 2], view.look, atol=1e-9)
        np.testing.assert_allclose(frame.c2w[:3, 2], -arkit[:3, 2], atol=1e-9)
        np.testing.assert_allclose(frame.c2w[:3, 1], [0.0, -1.0, 0.0], atol=1e-9)
        np.testing.assert_allclose(frame.c2w[:3, 0], arkit[:3, 0], atol=1e-9)
        _assert_wall(frame, view)


def _assert_wall(frame: Frame, view: View) -> None:
    points, _ = backproject(frame)
    assert len(points) == WIDTH * HEIGHT - 4  # the depth pixel without depth covers 2x2
    np.testing.assert_allclose(points[:, view.wall_axis], view.wall_at, atol=1e-5)
    grid = np.full((HEIGHT, WIDTH, 3), np.nan)
    rows, cols = np.nonzero(frame.depth > 0)
    grid[rows, cols] = points
    # image rows grow downwards: the top row is above the bottom row in the y-up world
    assert np.all(grid[0, 2:, 1] > grid[-1, 2:, 1])
    # image columns grow to the camera's right: ARKit's camera x axis in the world
    right = np.asarray(arkit_matrix(view)[:3, 0])
    assert np.all((grid[2:, -1] - grid[2:, 0]) @ right > 0)
