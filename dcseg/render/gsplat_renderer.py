"""The CUDA backend: gsplat's fused kernels (optional ``[cuda]`` extra, imported lazily)."""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor

from dcseg.gaussians import Gaussians
from dcseg.render.camera import Camera
from dcseg.render.projection import EPS2D, NEAR_PLANE


def render_gsplat(
    gaussians: Gaussians, values: Tensor, camera: Camera
) -> tuple[Tensor, Tensor, Tensor]:  # pragma: no cover - needs CUDA and gsplat
    """Render with ``gsplat.rasterization`` (classic mode, unpacked, expected depth).

    Args:
        gaussians: N Gaussians on a CUDA device.
        values: ``[N, C]`` per-Gaussian values.
        camera: the camera.

    Returns:
        ``values [H, W, C]``, ``alpha [H, W]``, ``depth [H, W]`` (no background).
    """
    from gsplat import rasterization

    cam = camera.to(gaussians.device, gaussians.means.dtype)
    colors, alphas, _ = rasterization(**_arguments(gaussians, values, cam))
    return colors[0, ..., :-1], alphas[0, ..., 0], colors[0, ..., -1]


def _arguments(gaussians: Gaussians, values: Tensor, cam: Camera) -> dict[str, Any]:
    """Keyword arguments of ``gsplat.rasterization`` for one camera."""
    k = cam.K.clone()
    k[:2, 2] += 0.5  # gsplat puts pixel centres at +0.5, dcseg at integers
    return {
        "means": gaussians.means,
        "quats": gaussians.quats,
        "scales": torch.exp(gaussians.log_scales),
        "opacities": torch.sigmoid(gaussians.opacity_logits),
        "colors": values,
        "viewmats": cam.viewmat()[None],
        "Ks": k[None],
        "width": cam.width,
        "height": cam.height,
        "near_plane": NEAR_PLANE,
        "eps2d": EPS2D,
        "sh_degree": None,
        "packed": False,
        "render_mode": "RGB+ED",
        "rasterize_mode": "classic",
    }
