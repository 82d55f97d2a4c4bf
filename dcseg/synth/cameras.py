"""Camera path, intrinsics and the OpenGL <-> OpenCV conversions for pybullet's renderer.

pybullet follows OpenGL: view matrices map world to a camera with x right, y up and z backward,
matrices are passed flattened column-major, and the depth buffer holds non-linear window depth
in [0, 1]. dcseg uses OpenCV axes (x right, y down, z forward) and metric z-depth. Everything
here is pure numpy so it can be tested without pybullet.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from dcseg.types import Intrinsics

GL_FROM_CV = np.diag([1.0, -1.0, -1.0, 1.0])
"""Flips y and z: turns OpenCV camera axes into OpenGL camera axes (its own inverse)."""

WORLD_UP = np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class CameraModel:
    """A pinhole camera as pybullet renders it.

    Attributes:
        width, height: image size in pixels.
        fov_deg: vertical field of view in degrees.
        near, far: clipping planes in metres.
        shift: moves the image content by this many pixels along +u and +v (0 = the symmetric
            frustum of :meth:`intrinsics`); :meth:`supersampled` uses it to align block averages.
    """

    width: int
    height: int
    fov_deg: float = 60.0
    near: float = 0.05
    far: float = 12.0
    shift: float = 0.0

    def supersampled(self, factor: int) -> CameraModel:
        """The same view at ``factor`` x the resolution, shifted so that averaging its
        ``factor x factor`` blocks gives pixels centred where this camera's are.

        Block averaging maps a fine pixel centre ``u_f`` to ``(u_f + 0.5) / factor - 0.5``, so
        the fine principal point must move by ``(factor - 1) / 2`` fine pixels (measured:
        phase correlation of the averaged image against this camera's is below 0.15 px).
        """
        return CameraModel(
            self.width * factor, self.height * factor, self.fov_deg, self.near, self.far,
            shift=(factor - 1) / 2.0,
        )  # fmt: skip

    def intrinsics(self) -> Intrinsics:
        """Pinhole intrinsics of TinyRenderer images made with :meth:`projection_matrix`.

        ``fx = fy = H / 2 / tan(fov / 2)``. TinyRenderer samples OpenGL pixel *corners* (window
        x = column, window y = row index before its vertical flip), which in dcseg's
        pixel-centre convention puts the principal point at ``(W / 2, H / 2 - 1)``; the
        reprojection test checks this to sub-millimetre depth agreement.
        """
        f = self.height / 2.0 / math.tan(math.radians(self.fov_deg) / 2.0)
        cx, cy = self.width / 2.0, self.height / 2.0 - 1.0
        return Intrinsics(fx=f, fy=f, cx=cx, cy=cy, width=self.width, height=self.height)

    def projection_matrix(self) -> list[float]:
        """The OpenGL perspective matrix, flattened column-major (as pybullet expects).

        Same as ``pybullet.computeProjectionMatrixFOV(fov, width / height, near, far)``.
        """
        f = 1.0 / math.tan(math.radians(self.fov_deg) / 2.0)
        aspect = self.width / self.height
        n, fa = self.near, self.far
        proj = np.array(
            [
                [f / aspect, 0.0, -2.0 * self.shift / self.width, 0.0],
                [0.0, f, -2.0 * self.shift / self.height, 0.0],
                [0.0, 0.0, (fa + n) / (n - fa), 2.0 * fa * n / (n - fa)],
                [0.0, 0.0, -1.0, 0.0],
            ]
        )
        return [float(v) for v in proj.T.reshape(-1)]

    def linear_depth(self, buffer: NDArray[np.floating]) -> NDArray[np.float32]:
        """Metric z-depth from a depth buffer; background (buffer == 1) becomes 0 (invalid).

        Args:
            buffer: ``[H, W]`` window depth in [0, 1] as returned by ``getCameraImage``.

        Returns:
            ``[H, W]`` float32 z-depth in metres (distance along the optical axis, not the ray).
        """
        d = np.asarray(buffer, dtype=np.float64)
        z = self.far * self.near / (self.far - (self.far - self.near) * d)
        z[d >= 1.0 - 1e-7] = 0.0
        return z.astype(np.float32)


def look_at(eye: NDArray[np.float64], target: NDArray[np.float64]) -> NDArray[np.float64]:
    """Camera-to-world pose (OpenCV axes) of a camera at ``eye`` looking at ``target``.

    The world is z-up; image rows point down (towards -z) and the camera does not roll.
    """
    forward = target - eye
    forward = forward / np.linalg.norm(forward)
    right = np.cross(forward, WORLD_UP)
    right = right / np.linalg.norm(right)
    down = np.cross(forward, right)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, down, forward, eye
    return c2w


def view_matrix(c2w: NDArray[np.float64]) -> list[float]:
    """pybullet's OpenGL view matrix (world-to-camera, flattened column-major) for a pose."""
    w2c_gl = GL_FROM_CV @ np.linalg.inv(c2w)
    return [float(v) for v in w2c_gl.T.reshape(-1)]


def orbit_poses(
    n: int, rng: np.random.Generator, centre: NDArray[np.float64], radii: tuple[float, float]
) -> NDArray[np.float64]:
    """A seeded loop of ``n`` cameras around ``centre`` at varying height, looking inward/down.

    Args:
        n: number of cameras.
        rng: seeded generator (start angle, height/radius waves, look-at jitter).
        centre: ``[3]`` point the loop goes around (z is ignored).
        radii: ``(rx, ry)`` semi-axes of the elliptical loop in metres.

    Returns:
        ``[n, 4, 4]`` camera-to-world poses, OpenCV axes.
    """
    start = rng.uniform(0.0, 2.0 * math.pi)
    phase = rng.uniform(0.0, 2.0 * math.pi, size=2)
    poses = np.empty((n, 4, 4))
    for i in range(n):
        t = 2.0 * math.pi * i / n
        angle = start + t + rng.normal(0.0, 0.5 / max(n, 1))
        scale = 0.85 + 0.15 * math.sin(2.0 * t + phase[0])
        eye = np.array(
            [
                centre[0] + radii[0] * scale * math.cos(angle),
                centre[1] + radii[1] * scale * math.sin(angle),
                1.35 + 0.3 * math.sin(3.0 * t + phase[1]),
            ]
        )
        target = np.array([centre[0], centre[1], 0.45]) + rng.normal(0.0, [0.35, 0.35, 0.1])
        poses[i] = look_at(eye, target)
    return poses
