"""The numba ``cpu`` backend against the PyTorch reference: forward and every gradient."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch import Tensor

from dcseg.gaussians import Gaussians
from dcseg.render import Camera, RenderOutput, render
from dcseg.render.numba_kernels import balanced_tiles
from tests.scenes import gaussians as scenes

NAMES = ("means", "quats", "log_scales", "opacity_logits", "values")


def _render_and_grads(
    gaussians: Gaussians, vals: Tensor, cam: Camera, backend: str
) -> tuple[RenderOutput, list[Tensor]]:
    out = render(gaussians, vals, cam, backend=backend)
    gen = torch.Generator().manual_seed(7)
    weights = torch.randn(out.values.shape, generator=gen, dtype=out.values.dtype)
    loss = (out.values * weights).sum() + 0.7 * out.alpha.sum() + 0.1 * out.depth.sum()
    grads = torch.autograd.grad(loss, [*scenes.parameters(gaussians), vals])
    return out, list(grads)


def _compare(dtype: torch.dtype, n: int, channels: int, rtol: float, seed: int = 0) -> None:
    gaussians = scenes.scene(n, seed=seed, dtype=dtype)
    vals = scenes.values(n, channels, dtype=dtype)
    cam = scenes.camera(dtype=dtype)
    ref, ref_grads = _render_and_grads(gaussians, vals, cam, "reference")
    cpu, cpu_grads = _render_and_grads(gaussians, vals, cam, "cpu")
    assert float(ref.alpha.detach().max()) > 0.5  # the scene is not empty
    for field in ("values", "alpha", "depth"):
        a, b = getattr(ref, field), getattr(cpu, field)
        torch.testing.assert_close(b, a, rtol=rtol, atol=rtol * float(a.detach().abs().max()))
    for name, a, b in zip(NAMES, ref_grads, cpu_grads, strict=True):
        scale = float(a.detach().abs().max())
        assert scale > 0, name
        torch.testing.assert_close(b, a, rtol=rtol, atol=rtol * scale, msg=name)


@pytest.mark.parametrize("channels", [1, 3, 32])
def test_cpu_matches_reference_float64(channels: int) -> None:
    """float64: forward and gradients agree to 1e-8 relative (of the largest entry)."""
    _compare(torch.float64, n=150, channels=channels, rtol=1e-8)


def test_cpu_matches_reference_float32() -> None:
    """float32: forward and gradients agree to 1e-4 relative (of the largest entry)."""
    _compare(torch.float32, n=150, channels=3, rtol=1e-4, seed=3)


def test_cpu_matches_reference_dense_scene() -> None:
    """Many overlapping Gaussians: early termination (T < 1e-4) and the alpha clamp kick in."""
    gaussians = scenes.scene(400, seed=5)
    with torch.no_grad():
        gaussians.opacity_logits.add_(4.0)
        gaussians.opacity_logits[:40] = 9.0  # opacity > 0.999: the alpha clamp applies
        gaussians.log_scales.add_(0.7)
    vals = scenes.values(400, 4)
    cam = scenes.camera()
    ref, ref_grads = _render_and_grads(gaussians, vals, cam, "reference")
    cpu, cpu_grads = _render_and_grads(gaussians, vals, cam, "cpu")
    saturated = (ref.alpha.detach() > 0.999).double().mean()
    assert float(saturated) > 0.5  # most pixels stop early (transmittance <= 1e-4)
    torch.testing.assert_close(cpu.values, ref.values, rtol=1e-8, atol=1e-10)
    for name, a, b in zip(NAMES, ref_grads, cpu_grads, strict=True):
        torch.testing.assert_close(
            b, a, rtol=1e-8, atol=1e-8 * float(a.detach().abs().max()), msg=name
        )


def _tiny_case() -> tuple[list[Tensor], Camera]:
    """Three large, well-separated Gaussians on an 8x6 image: smooth in every input."""
    dtype = torch.float64
    means = torch.tensor([[0.0, 0.0, 2.0], [0.3, -0.1, 2.5], [-0.2, 0.2, 3.0]], dtype=dtype)
    quats = torch.tensor([[1.0, 0.1, 0.2, 0.0], [0.9, 0.0, -0.3, 0.2], [1.0, 0.3, 0.0, 0.1]])
    log_scales = torch.log(torch.tensor([[0.8, 0.6, 0.5], [0.7, 0.9, 0.4], [1.0, 0.8, 0.6]]))
    logits = torch.tensor([0.5, -0.2, 1.0], dtype=dtype)
    vals = torch.tensor([[0.2, 0.9], [0.7, 0.1], [0.5, 0.5]], dtype=dtype)
    tensors = [means, quats.double(), log_scales.double(), logits, vals]
    k = torch.tensor([[6.0, 0.0, 3.5], [0.0, 6.0, 2.5], [0.0, 0.0, 1.0]], dtype=dtype)
    return [t.requires_grad_(True) for t in tensors], Camera(torch.eye(4, dtype=dtype), k, 8, 6)


@pytest.mark.parametrize("backend", ["reference", "cpu"])
def test_gradcheck(backend: str) -> None:
    """Analytic (cpu) and autograd (reference) gradients match finite differences."""
    inputs, cam = _tiny_case()

    def fn(*t: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        g = Gaussians(t[0], t[1], t[2], t[3], torch.zeros(3, 1, 3, dtype=torch.float64))
        out = render(g, t[4], cam, backend=backend, background=torch.tensor([0.3, 0.1]))
        return out.values, out.alpha, out.depth

    assert torch.autograd.gradcheck(
        fn, tuple(inputs), eps=1e-6, atol=1e-6, rtol=1e-5, fast_mode=True
    )


@pytest.mark.parametrize("workers", [1, 2, 3])
def test_balanced_tiles_cover_every_tile_once(workers: int) -> None:
    """Each tile goes to exactly one worker; loads differ by at most the largest tile's cost."""

    lengths = np.random.default_rng(0).integers(0, 3000, size=300)
    offsets = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)
    order, starts = balanced_tiles(offsets, workers)
    assert sorted(order.tolist()) == list(range(300))
    assert starts[0] == 0 and starts[-1] == 300 and len(starts) == workers + 1
    bounds = zip(starts[:-1], starts[1:], strict=True)
    loads = [int((lengths[order[a:b]] + 32).sum()) for a, b in bounds]
    assert max(loads) - min(loads) <= int(lengths.max()) + 32
