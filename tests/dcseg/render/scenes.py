"""Random Gaussian scenes and cameras for the renderer tests."""

from __future__ import annotations

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
