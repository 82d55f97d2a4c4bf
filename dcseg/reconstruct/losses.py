"""Image losses and metrics of the reconstruction stage (pure functions over ``[H, W, C]``)."""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor

SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
_C1 = 0.01**2
_C2 = 0.03**2


def l1_loss(pred: Tensor, target: Tensor) -> Tensor:
    """Mean absolute difference."""
    return (pred - target).abs().mean()


def _gaussian_kernel(like: Tensor) -> Tensor:
    """The normalised 1-D Gaussian of the SSIM window (the 2-D window is its outer product)."""
    coords = torch.arange(SSIM_WINDOW, dtype=like.dtype, device=like.device) - SSIM_WINDOW // 2
    g = torch.exp(-(coords**2) / (2.0 * SSIM_SIGMA**2))
    return g / g.sum()


def _blur(maps: Tensor) -> Tensor:
    """Zero-padded separable Gaussian blur of ``[1, C, H, W]`` maps (same as the 2-D window)."""
    channels = maps.shape[1]
    g = _gaussian_kernel(maps)
    pad = SSIM_WINDOW // 2
    rows = g.view(1, 1, SSIM_WINDOW, 1).expand(channels, 1, SSIM_WINDOW, 1)
    cols = g.view(1, 1, 1, SSIM_WINDOW).expand(channels, 1, 1, SSIM_WINDOW)
    out = F.conv2d(maps, rows, padding=(pad, 0), groups=channels)
    return F.conv2d(out, cols, padding=(0, pad), groups=channels)


def ssim(pred: Tensor, target: Tensor) -> Tensor:
    """Mean structural similarity with an 11x11 Gaussian window (sigma 1.5), as in 3DGS.

    Args:
        pred: ``[H, W, C]`` image in [0, 1].
        target: ``[H, W, C]`` image in [0, 1].

    Returns:
        Scalar SSIM (1 for identical images), zero-padded borders like the 3DGS code.
    """
    x = pred.permute(2, 0, 1)
    y = target.permute(2, 0, 1)
    c = x.shape[0]
    blurred = _blur(torch.cat([x, y, x * x, y * y, x * y]).unsqueeze(0))[0]
    mu_x, mu_y, e_xx, e_yy, e_xy = (blurred[i * c : (i + 1) * c] for i in range(5))
    mu_xx, mu_yy, mu_xy = mu_x * mu_x, mu_y * mu_y, mu_x * mu_y
    var_x, var_y, cov = e_xx - mu_xx, e_yy - mu_yy, e_xy - mu_xy
    numerator = (2.0 * mu_xy + _C1) * (2.0 * cov + _C2)
    denominator = (mu_xx + mu_yy + _C1) * (var_x + var_y + _C2)
    value: Tensor = (numerator / denominator).mean()
    return value


def rgb_loss(pred: Tensor, target: Tensor, ssim_lambda: float) -> Tensor:
    """The 3DGS photometric loss ``(1 - l) * L1 + l * (1 - SSIM)``."""
    loss = l1_loss(pred, target)
    if ssim_lambda > 0.0:
        loss = (1.0 - ssim_lambda) * loss + ssim_lambda * (1.0 - ssim(pred, target))
    return loss


def depth_l1(pred: Tensor, target: Tensor) -> Tensor:
    """Mean absolute depth error over pixels with valid target depth (> 0); 0 when there are none.

    Args:
        pred: ``[H, W]`` rendered depth (metres).
        target: ``[H, W]`` measured depth (metres), 0 = invalid.
    """
    valid = target > 0
    if not bool(valid.any()):
        return pred.sum() * 0.0
    return (pred[valid] - target[valid]).abs().mean()


def psnr(pred: Tensor, target: Tensor) -> float:
    """Peak signal-to-noise ratio in dB of images in [0, 1] (inf when identical)."""
    mse = float(((pred.clamp(0.0, 1.0) - target) ** 2).mean())
    return math.inf if mse == 0.0 else -10.0 * math.log10(mse)
