"""Losses and metrics: SSIM, L1 on valid depth, PSNR."""

from __future__ import annotations

import math

import torch

from dcseg.reconstruct.losses import depth_l1, l1_loss, psnr, rgb_loss, ssim


def image(seed: int = 0, h: int = 24, w: int = 32) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    smooth = torch.nn.functional.avg_pool2d(torch.rand(1, 3, h, w, generator=g), 3, 1, 1)
    return smooth[0].permute(1, 2, 0).contiguous()


def test_ssim_of_identical_images_is_one() -> None:
    x = image()
    assert abs(float(ssim(x, x)) - 1.0) < 1e-5


def test_ssim_decreases_with_noise() -> None:
    x = image()
    g = torch.Generator().manual_seed(1)
    noise = torch.randn(x.shape, generator=g)
    values = [float(ssim((x + s * noise).clamp(0, 1), x)) for s in (0.0, 0.02, 0.1, 0.3)]
    assert all(a > b for a, b in zip(values, values[1:], strict=False))


def test_ssim_is_differentiable() -> None:
    x = image().requires_grad_(True)
    torch.autograd.backward(1.0 - ssim(x, image(2)))
    assert x.grad is not None and bool(torch.isfinite(x.grad).all())


def test_rgb_loss_mixes_l1_and_ssim() -> None:
    x, y = image(0), image(1)
    expected = 0.8 * l1_loss(x, y) + 0.2 * (1.0 - ssim(x, y))
    assert torch.allclose(rgb_loss(x, y, 0.2), expected)
    assert torch.allclose(rgb_loss(x, y, 0.0), l1_loss(x, y))


def test_depth_l1_uses_valid_pixels_only() -> None:
    target = torch.tensor([[1.0, 0.0], [2.0, 0.0]])
    pred = torch.tensor([[1.5, 9.0], [1.0, -4.0]])
    assert math.isclose(float(depth_l1(pred, target)), 0.75)
    assert float(depth_l1(pred, torch.zeros(2, 2))) == 0.0


def test_psnr() -> None:
    x = torch.zeros(4, 4, 3)
    assert psnr(x, x) == math.inf
    assert math.isclose(psnr(x + 0.1, x), 20.0, rel_tol=1e-5)


def test_ssim_matches_the_dense_11x11_window() -> None:
    x, y = image(3), image(4)
    coords = torch.arange(11, dtype=torch.float32) - 5
    g = torch.exp(-(coords**2) / (2 * 1.5**2))
    window = torch.outer(g, g) / g.sum() ** 2
    w = window.expand(3, 1, 11, 11)

    def blur(t: torch.Tensor) -> torch.Tensor:
        return torch.nn.functional.conv2d(t, w, padding=5, groups=3)

    a, b = x.permute(2, 0, 1)[None], y.permute(2, 0, 1)[None]
    mu_a, mu_b = blur(a), blur(b)
    var_a = blur(a * a) - mu_a**2
    var_b = blur(b * b) - mu_b**2
    cov = blur(a * b) - mu_a * mu_b
    c1, c2 = 0.01**2, 0.03**2
    dense = ((2 * mu_a * mu_b + c1) * (2 * cov + c2)) / (
        (mu_a**2 + mu_b**2 + c1) * (var_a + var_b + c2)
    )
    assert torch.allclose(ssim(x, y), dense.mean(), atol=1e-6)
