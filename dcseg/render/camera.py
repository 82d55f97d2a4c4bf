"""The camera and the output of :func:`dcseg.render.render`.

Conventions: OpenCV camera axes (x right, y down, z forward), 4x4 camera-to-world poses, pixel
centres at integer coordinates (``u`` = column, ``v`` = row), so a centred principal point is
``cx = W / 2 - 0.5``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from dcseg.types import Frame


@dataclass(frozen=True)
class Camera:
    """One pinhole camera.

    Attributes:
        c2w: ``[4, 4]`` camera-to-world rigid transform, OpenCV axes (as ``Frame.c2w``).
        K: ``[3, 3]`` intrinsics matrix (pixel centres at integer coordinates).
        width: image width W in pixels.
        height: image height H in pixels.
    """

    c2w: Tensor
    K: Tensor
    width: int
    height: int

    def __post_init__(self) -> None:
        if tuple(self.c2w.shape) != (4, 4):
            raise ValueError(f"Camera.c2w must have shape (4, 4), got {tuple(self.c2w.shape)}")
        if tuple(self.K.shape) != (3, 3):
            raise ValueError(f"Camera.K must have shape (3, 3), got {tuple(self.K.shape)}")
        if self.width < 1 or self.height < 1:
            raise ValueError(f"Camera size must be positive, got {self.width}x{self.height}")

    def viewmat(self) -> Tensor:
        """The ``[4, 4]`` world-to-camera matrix (closed-form inverse of the rigid ``c2w``)."""
        rot = self.c2w[:3, :3]
        out = torch.zeros_like(self.c2w)
        out[:3, :3] = rot.T
        out[:3, 3] = -(rot.T @ self.c2w[:3, 3])
        out[3, 3] = 1.0
        return out

    def to_camera(self, points: Tensor) -> Tensor:
        """``[N, 3]`` world ``points`` in this camera's frame (OpenCV axes, z forward), in their
        dtype and on their device; differentiable in ``points``."""
        return (points - self.c2w[:3, 3].to(points)) @ self.c2w[:3, :3].to(points)

    def to_pixels(self, cam: Tensor) -> Tensor:
        """``[N, 2]`` pixel coordinates ``(u, v)`` of camera-frame points ``cam`` (depth
        clamped at 1e-6, so points behind the camera get finite, meaningless coordinates)."""
        k = self.K.to(cam)
        z = cam[:, 2].clamp_min(1e-6)
        u = k[0, 0] * cam[:, 0] / z + k[0, 2]
        return torch.stack([u, k[1, 1] * cam[:, 1] / z + k[1, 2]], dim=1)

    def to(self, device: torch.device | str, dtype: torch.dtype) -> Camera:
        """The same camera with its tensors on ``device`` in ``dtype``."""
        return Camera(
            self.c2w.to(device=device, dtype=dtype),
            self.K.to(device=device, dtype=dtype),
            self.width,
            self.height,
        )

    @classmethod
    def from_frame(
        cls,
        frame: Frame,
        device: torch.device | str = "cpu",
        dtype: torch.dtype = torch.float32,
    ) -> Camera:
        """The camera of a captured frame (its pose, intrinsics and image size)."""
        k = np.array(frame.intrinsics.matrix(), dtype=np.float64)
        c2w = np.array(frame.c2w, dtype=np.float64)
        return cls(
            torch.tensor(c2w, device=device, dtype=dtype),
            torch.tensor(k, device=device, dtype=dtype),
            frame.intrinsics.width,
            frame.intrinsics.height,
        )


@dataclass(frozen=True)
class RenderOutput:
    """What :func:`dcseg.render.render` returns.

    Attributes:
        values: ``[H, W, C]`` alpha-blended per-Gaussian values, plus
            ``background * (1 - alpha)`` when a background is given.
        alpha: ``[H, W]`` accumulated opacity ``1 - T``.
        depth: ``[H, W]`` expected view-space z, ``sum(w_i z_i) / max(alpha, 1e-10)``; 0 where
            nothing was hit (alpha is either 0 or at least 1/255, so no other pixel is affected).
    """

    values: Tensor
    alpha: Tensor
    depth: Tensor
