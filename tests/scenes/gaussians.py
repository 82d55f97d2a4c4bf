"""Gaussians and cameras built in code: random scenes for the renderer tests, and Gaussians at
chosen places (a tilted disc, walls) whose renders have closed forms."""

from __future__ import annotations

import math

import torch
from torch import Tensor

from dcseg.gaussians import Gaussians
from dcseg.render import Camera


def camera(width: int = 40, height: int = 30, dtype: torch.dtype = torch.float64) -> Camera:
    """A camera at the origin looking down +z with a centred principal point."""
    focal = 0.9 * width
    k = torch.tensor(
        [[focal, 0.0, width / 2 - 0.5], [0.0, focal * 1.1, height / 2 - 0.5], [0.0, 0.0, 1.0]],
        dtype=dtype,
    )
    return Camera(torch.eye(4, dtype=dtype), k, width, height)


def scene(
    n: int, *, seed: int = 0, dtype: torch.dtype = torch.float64, grad: bool = True
) -> Gaussians:
    """N random Gaussians 1.5-4.5 m in front of :func:`camera`, some partly off screen."""
    gen = torch.Generator().manual_seed(seed)
    z = 1.5 + 3.0 * torch.rand(n, generator=gen, dtype=dtype)
    xy = (torch.rand(n, 2, generator=gen, dtype=dtype) - 0.5) * 1.4 * z[:, None]
    tensors = [
        torch.cat([xy, z[:, None]], dim=1),
        torch.randn(n, 4, generator=gen, dtype=dtype),
        torch.log(0.03 * z)[:, None] + 0.6 * torch.randn(n, 3, generator=gen, dtype=dtype),
        torch.randn(n, generator=gen, dtype=dtype) + 0.5,
    ]
    if grad:
        tensors = [t.requires_grad_(True) for t in tensors]
    means, quats, log_scales, logits = tensors
    return Gaussians(means, quats, log_scales, logits, torch.zeros(n, 1, 3, dtype=dtype))


def values(n: int, channels: int, *, seed: int = 1, dtype: torch.dtype = torch.float64) -> Tensor:
    gen = torch.Generator().manual_seed(seed)
    return torch.rand(n, channels, generator=gen, dtype=dtype).requires_grad_(True)


def parameters(gaussians: Gaussians) -> list[Tensor]:
    """The differentiable tensors of a scene, in a fixed order."""
    return [gaussians.means, gaussians.quats, gaussians.log_scales, gaussians.opacity_logits]


def gaussians_at(
    means: Tensor, log_scales: Tensor, opacity_logits: Tensor, sh: Tensor | None = None
) -> Gaussians:
    """Gaussians at ``means`` with identity rotations; ``sh`` defaults to black at degree 0."""
    n = means.shape[0]
    quats = torch.zeros(n, 4, dtype=means.dtype)
    quats[:, 0] = 1.0
    colour = torch.zeros(n, 1, 3, dtype=means.dtype) if sh is None else sh
    return Gaussians(means, quats, log_scales, opacity_logits, colour)


def tilted_disc(angle: float, *, thickness: float = 1e-7) -> Gaussians:
    """One opaque disc 2 m ahead, 0.4 m wide, its normal turned ``angle`` about the y axis."""
    half = angle / 2
    quat = torch.tensor([[math.cos(half), 0.0, math.sin(half), 0.0]], dtype=torch.float64)
    scales = torch.tensor([[0.4, 0.4, thickness]], dtype=torch.float64).log()
    return Gaussians(
        torch.tensor([[0.1, 0.0, 2.0]], dtype=torch.float64),
        quat,
        scales,
        torch.tensor([4.0], dtype=torch.float64),
        torch.zeros(1, 1, 3, dtype=torch.float64),
    )


def ray_plane_depth(disc: Gaussians, u: Tensor, v: Tensor, k: Tensor) -> Tensor:
    """Exact depth where each pixel's ray meets the disc's plane (camera = world)."""
    angle = 2 * math.atan2(float(disc.quats[0, 2]), float(disc.quats[0, 0]))
    normal = torch.tensor([math.sin(angle), 0.0, math.cos(angle)], dtype=torch.float64)
    rays = torch.stack([(u - k[0, 2]) / k[0, 0], (v - k[1, 2]) / k[1, 1], torch.ones_like(u)], -1)
    return (normal @ disc.means[0]) / (rays @ normal)
