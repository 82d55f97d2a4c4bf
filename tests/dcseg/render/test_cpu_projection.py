"""The numba projection of the ``cpu`` backend against the PyTorch projection it replaces."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
import torch
from torch import Tensor

from dcseg.gaussians import Gaussians
from dcseg.render import Camera
from dcseg.render import numba_projection as npj
from dcseg.render.cpu_projection import project_cpu
from dcseg.render.projection import Splats, project
from tests.scenes import gaussians as scenes


def _posed_camera(dtype: torch.dtype) -> Camera:
    """The test camera rotated 20 degrees about y and moved, so every view matrix entry is used."""
    cam = scenes.camera(dtype=dtype)
    angle = math.radians(20.0)
    c2w = torch.eye(4, dtype=dtype)
    c2w[0, 0], c2w[0, 2], c2w[2, 0], c2w[2, 2] = (
        math.cos(angle), math.sin(angle), -math.sin(angle), math.cos(angle)
    )  # fmt: skip
    c2w[:3, 3] = torch.tensor([0.4, -0.2, -0.3], dtype=dtype)
    return Camera(c2w, cam.K, cam.width, cam.height)


def _wide_scene(dtype: torch.dtype) -> Gaussians:
    """Random Gaussians plus large ones far outside the field of view (the clamp of ``J``)."""
    g = scenes.scene(120, seed=11, dtype=dtype, grad=False)
    gen = torch.Generator().manual_seed(4)
    z = 2.0 + torch.rand(30, generator=gen, dtype=dtype)
    side = torch.where(torch.rand(30, generator=gen) < 0.5, -1.0, 1.0).to(dtype)
    xy = torch.stack([side * 1.1 * z, 0.2 * torch.randn(30, generator=gen, dtype=dtype)], 1)
    tensors = [
        torch.cat([g.means, torch.cat([xy, z[:, None]], 1)]),
        torch.cat([g.quats, torch.randn(30, 4, generator=gen, dtype=dtype)]),
        torch.cat([g.log_scales, torch.full((30, 3), math.log(0.9), dtype=dtype)]),
        torch.cat([g.opacity_logits, torch.full((30,), 2.0, dtype=dtype)]),
    ]
    means, quats, log_scales, logits = (t.clone().requires_grad_(True) for t in tensors)
    return Gaussians(means, quats, log_scales, logits, torch.zeros(150, 1, 3, dtype=dtype))


def _loss(splats: Splats) -> Tensor:
    """A fixed random linear function of every differentiable output (indexed by Gaussian)."""
    gen = torch.Generator().manual_seed(9)
    n = 150
    outputs = (splats.means2d, splats.conics, splats.opacities[:, None], splats.depths[:, None])
    total = splats.depths.sum() * 0.0
    for out in outputs:
        weights = torch.randn(n, out.shape[1], generator=gen, dtype=out.dtype)
        total = total + (out * weights[splats.index]).sum()
    return total


def _compare(dtype: torch.dtype, rtol: float) -> None:
    gaussians, cam = _wide_scene(dtype), _posed_camera(dtype)
    ref, fast = project(gaussians, cam), project_cpu(gaussians, cam)
    assert torch.equal(fast.index, ref.index)
    u = ref.means2d.detach()[:, 0]
    clamped = (u < -0.2 * cam.width) | (u > 1.2 * cam.width)
    assert int(clamped.sum()) >= 3  # splats whose centre is outside the clamped frustum
    for name in ("means2d", "conics", "opacities", "depths"):
        a, b = getattr(ref, name), getattr(fast, name)
        scale = float(a.detach().abs().max())
        torch.testing.assert_close(b, a, rtol=rtol, atol=rtol * scale, msg=name)
    assert torch.equal(fast.tile_min, ref.tile_min) and torch.equal(fast.tile_max, ref.tile_max)
    leaves = [gaussians.means, gaussians.quats, gaussians.log_scales, gaussians.opacity_logits]
    expected = torch.autograd.grad(_loss(ref), leaves)
    got = torch.autograd.grad(_loss(fast), leaves)
    for a, b in zip(expected, got, strict=True):
        assert float(a.abs().max()) > 0
        torch.testing.assert_close(b, a, rtol=rtol, atol=rtol * float(a.abs().max()))


def test_matches_torch_projection_float64() -> None:
    """Same visible set, order, tiles, outputs and gradients, incl. clamped off-screen splats."""
    _compare(torch.float64, rtol=1e-9)


def test_matches_torch_projection_float32() -> None:
    """float32 inputs: agreement to 1e-4 relative of the largest entry."""
    _compare(torch.float32, rtol=1e-4)


def test_behind_camera_and_transparent_are_culled() -> None:
    """Gaussians behind the near plane, at z = 0 or with opacity < 1/255 are not projected."""
    dtype = torch.float64
    means = torch.tensor([[0.0, 0.0, 2.0], [0.0, 0.0, -1.0], [0.0, 0.0, 0.0], [0.1, 0.0, 2.0]])
    g = Gaussians(
        means.to(dtype),
        torch.tensor([[1.0, 0.0, 0.0, 0.0]] * 4, dtype=dtype),
        torch.full((4, 3), math.log(0.05), dtype=dtype),
        torch.tensor([1.0, 1.0, 1.0, -8.0], dtype=dtype),
        torch.zeros(4, 1, 3, dtype=dtype),
    )
    splats = project_cpu(g, scenes.camera())
    assert splats.index.tolist() == [0]
    assert bool(torch.isfinite(splats.conics).all())


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_boundary_cases_match_torch_projection(dtype: torch.dtype) -> None:
    """A centre exactly on the (rounded) near plane and a ~1e8 px radius: same decisions."""
    means = torch.tensor([[0.0, 0.0, 0.01], [0.0, 0.0, 1.0], [0.2, 0.1, 2.0]], dtype=dtype)
    log_scales = torch.tensor(
        [[math.log(1e-3)] * 3, [15.0, -3.0, -3.0], [math.log(0.05)] * 3], dtype=dtype
    )
    g = Gaussians(
        means,
        torch.tensor([[1.0, 0.0, 0.0, 0.0]] * 3, dtype=dtype),
        log_scales,
        torch.zeros(3, dtype=dtype),
        torch.zeros(3, 1, 3, dtype=dtype),
    )
    cam = scenes.camera(dtype=dtype)
    assert project_cpu(g, cam).index.tolist() == project(g, cam).index.tolist()


@pytest.mark.parametrize(("dtype", "bits"), [(np.float32, np.uint32), (np.float64, np.uint64)])
@pytest.mark.parametrize("n", [0, 1, 7, 5000])
def test_radix_argsort_is_a_stable_argsort(dtype: type, bits: type, n: int) -> None:
    """Positive floats (a third of them tied) sorted by their bit patterns as numpy sorts them."""
    rng = np.random.default_rng(n)
    values: np.ndarray[Any, Any] = rng.uniform(0.01, 10.0, n).astype(dtype)
    values[: n // 3] = values[n // 3 : 2 * (n // 3)]
    rng.shuffle(values)
    expected = np.argsort(values, kind="stable")
    assert np.array_equal(npj.radix_argsort(values.view(bits)), expected)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_equal_depths_keep_index_order(dtype: torch.dtype) -> None:
    """Splats at the same depth come in Gaussian order, as with the PyTorch projection."""
    g = scenes.scene(60, seed=3, dtype=dtype, grad=False)
    means = g.means.clone()
    means[:, 2] = torch.where(torch.arange(60) % 2 == 0, 2.0, 3.0).to(dtype)
    tied = Gaussians(means, g.quats, g.log_scales, g.opacity_logits, g.sh)
    cam = scenes.camera(dtype=dtype)
    fast, ref = project_cpu(tied, cam).index, project(tied, cam).index
    assert len(ref) > 10 and torch.equal(fast, ref)
