"""``dcseg.render``: API contract, edge cases, backend selection and a gsplat GPU check."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
import torch

import dcseg.render
from dcseg.gaussians import Gaussians
from dcseg.render import BACKEND_ENV, Camera, render, select_backend
from dcseg.render.gsplat_renderer import _arguments
from dcseg.render.torch_renderer import composite_reference
from dcseg.types import Frame, Intrinsics
from tests.scenes import gaussians as scenes

BACKENDS = ["reference", "cpu"]


def _gaussians(means: list[list[float]], log_scale: float, logit: float) -> Gaussians:
    n = len(means)
    return scenes.gaussians_at(
        torch.tensor(means, dtype=torch.float64).reshape(n, 3),
        torch.full((n, 3), log_scale, dtype=torch.float64),
        torch.full((n,), logit, dtype=torch.float64),
    )


def test_exports_sorted_and_complete() -> None:
    assert dcseg.render.__all__ == sorted(dcseg.render.__all__)
    for name in dcseg.render.__all__:
        assert hasattr(dcseg.render, name)


@pytest.mark.parametrize("backend", BACKENDS)
def test_single_gaussian_blob(backend: str) -> None:
    """An isotropic Gaussian renders a blob at its projection with the expected peak."""
    cam = scenes.camera(40, 30)
    g = _gaussians([[0.1, -0.05, 2.0]], math.log(0.05), 0.0)  # opacity 0.5
    out = render(g, torch.tensor([[2.0]], dtype=torch.float64), cam, backend=backend)
    k = cam.K
    u, v = float(k[0, 0] * 0.1 / 2.0 + k[0, 2]), float(k[1, 1] * -0.05 / 2.0 + k[1, 2])
    alpha = out.alpha.detach()
    row, col = np.unravel_index(int(alpha.argmax()), tuple(alpha.shape))
    assert (abs(col - u) <= 0.5) and (abs(row - v) <= 0.5)
    x, y, z = 0.1, -0.05, 2.0
    fx, fy = float(k[0, 0]), float(k[1, 1])
    jac = np.array([[fx / z, 0.0, -fx * x / z**2], [0.0, fy / z, -fy * y / z**2]])
    cov = 0.05**2 * jac @ jac.T + 0.3 * np.eye(2)
    d = np.array([col - u, row - v])
    expected = 0.5 * math.exp(-0.5 * float(d @ np.linalg.solve(cov, d)))
    assert float(alpha[row, col]) == pytest.approx(expected, rel=1e-6)
    assert float(out.values[row, col, 0]) == pytest.approx(2.0 * expected, rel=1e-6)
    assert float(out.depth[row, col]) == pytest.approx(2.0, rel=1e-9)
    assert float(out.alpha[0, 0]) == 0.0 and float(out.depth[0, 0]) == 0.0


@pytest.mark.parametrize("backend", BACKENDS)
def test_culled_gaussians_render_nothing(backend: str) -> None:
    """Behind the camera, at z = 0, off screen and zero opacity: empty image, zero gradients."""
    means = [[0.0, 0.0, -2.0], [0.0, 0.0, 0.0], [50.0, 0.0, 2.0], [0.0, 0.0, 2.0]]
    g = _gaussians(means, math.log(0.05), 0.0)
    with torch.no_grad():
        g.opacity_logits[3] = -30.0  # opacity ~ 1e-13
    params = [t.requires_grad_(True) for t in scenes.parameters(g)]
    vals = torch.ones(4, 2, dtype=torch.float64, requires_grad=True)
    out = render(g, vals, scenes.camera(), backend=backend)
    assert float(out.alpha.detach().abs().max()) == 0.0
    loss = out.values.sum() + out.depth.sum()
    for grad in torch.autograd.grad(loss, [*params, vals], allow_unused=True):
        assert grad is None or (torch.isfinite(grad).all() and float(grad.abs().max()) == 0.0)


@pytest.mark.parametrize("backend", BACKENDS)
def test_degenerate_scales_are_finite(backend: str) -> None:
    """Vanishing scales still render (the 0.3 px^2 dilation) with finite gradients."""
    g = _gaussians([[0.0, 0.0, 2.0], [0.02, 0.0, 3.0]], -30.0, 2.0)
    params = [t.requires_grad_(True) for t in scenes.parameters(g)]
    out = render(g, torch.ones(2, 1, dtype=torch.float64), scenes.camera(), backend=backend)
    assert float(out.alpha.detach().max()) > 0.5
    for grad in torch.autograd.grad(out.values.sum(), params, allow_unused=True):
        assert grad is not None and torch.isfinite(grad).all()


@pytest.mark.parametrize("backend", BACKENDS)
def test_empty_scene(backend: str) -> None:
    g = _gaussians([], 0.0, 0.0)
    vals = torch.zeros(0, 3, dtype=torch.float64)
    bg = torch.tensor([0.1, 0.2, 0.3], dtype=torch.float64)
    out = render(g, vals, scenes.camera(8, 6), backend=backend, background=bg)
    assert out.values.shape == (6, 8, 3) and out.alpha.shape == (6, 8) and out.depth.shape == (6, 8)
    torch.testing.assert_close(out.values, bg.expand(6, 8, 3))
    assert float(out.alpha.abs().max()) == 0.0


@pytest.mark.parametrize("backend", BACKENDS)
def test_one_pixel_image(backend: str) -> None:
    k = torch.tensor([[2.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 1.0]], dtype=torch.float64)
    cam = Camera(torch.eye(4, dtype=torch.float64), k, 1, 1)
    g = _gaussians([[0.0, 0.0, 2.0]], math.log(0.5), 0.0)
    out = render(g, torch.ones(1, 1, dtype=torch.float64), cam, backend=backend)
    assert out.values.shape == (1, 1, 1)
    assert float(out.alpha[0, 0]) == pytest.approx(0.5, rel=1e-12)


def test_backends_agree_with_posed_camera_and_background() -> None:
    """A rotated, translated camera and a background: cpu == reference."""
    g = scenes.scene(120, seed=2, grad=False)
    angle = 0.2
    rot = torch.tensor(
        [[math.cos(angle), 0, math.sin(angle)], [0, 1, 0], [-math.sin(angle), 0, math.cos(angle)]],
        dtype=torch.float64,
    )
    c2w = torch.eye(4, dtype=torch.float64)
    c2w[:3, :3], c2w[:3, 3] = rot, torch.tensor([0.3, -0.1, 0.2], dtype=torch.float64)
    cam = Camera(c2w, scenes.camera().K, 40, 30)
    vals, bg = torch.rand(120, 3, dtype=torch.float64), torch.tensor([1.0, 0.0, 0.5])
    a = render(g, vals, cam, backend="reference", background=bg)
    b = render(g, vals, cam, backend="cpu", background=bg)
    assert float(a.alpha.max()) > 0.5
    torch.testing.assert_close(b.values, a.values, rtol=1e-10, atol=1e-12)
    torch.testing.assert_close(b.depth, a.depth, rtol=1e-10, atol=1e-12)


def test_camera_viewmat_and_from_frame() -> None:
    c2w = np.eye(4)
    c2w[:3, :3] = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    c2w[:3, 3] = [1.0, 2.0, 3.0]
    frame = Frame(
        "f0",
        np.zeros((6, 8, 3), np.uint8),
        np.zeros((6, 8), np.float32),
        Intrinsics(5.0, 6.0, 3.5, 2.5, 8, 6),
        c2w,
    )
    cam = Camera.from_frame(frame, dtype=torch.float64)
    assert (cam.width, cam.height) == (8, 6) and cam.c2w.dtype == torch.float64
    torch.testing.assert_close(cam.viewmat() @ cam.c2w, torch.eye(4, dtype=torch.float64))
    torch.testing.assert_close(cam.K[1, 1], torch.tensor(6.0, dtype=torch.float64))


def test_invalid_inputs() -> None:
    g = _gaussians([[0.0, 0.0, 2.0]], 0.0, 0.0)
    cam = scenes.camera()
    with pytest.raises(ValueError, match="values must have shape"):
        render(g, torch.ones(2, 3), cam)
    with pytest.raises(ValueError, match="background must have shape"):
        render(g, torch.ones(1, 3), cam, background=torch.ones(2))
    with pytest.raises(ValueError, match="unknown render backend"):
        render(g, torch.ones(1, 3), cam, backend="opengl")
    with pytest.raises(ValueError, match="Camera.K"):
        Camera(torch.eye(4), torch.eye(4), 8, 6)
    with pytest.raises(ValueError, match="Camera.c2w"):
        Camera(torch.eye(3), torch.eye(3), 8, 6)
    with pytest.raises(ValueError, match="Camera size"):
        Camera(torch.eye(4), torch.eye(3), 0, 6)


def test_backend_selection(monkeypatch: pytest.MonkeyPatch) -> None:
    cpu, cuda = torch.device("cpu"), torch.device("cuda")
    monkeypatch.delenv(BACKEND_ENV, raising=False)
    assert select_backend(cpu) == "cpu"
    assert select_backend(cpu, "reference") == "reference"
    monkeypatch.setenv(BACKEND_ENV, "reference")
    assert select_backend(cpu) == "reference"
    assert select_backend(cpu, "cpu") == "cpu"  # the argument wins over the variable
    monkeypatch.setenv(BACKEND_ENV, "vulkan")
    with pytest.raises(ValueError, match="unknown render backend 'vulkan'"):
        select_backend(cpu)
    monkeypatch.delenv(BACKEND_ENV)
    with pytest.raises(ValueError, match="needs CUDA"):
        select_backend(cpu, "gsplat")
    with pytest.raises(ValueError, match="needs CPU"):
        select_backend(cuda, "cpu")
    monkeypatch.setattr("dcseg.render.backend.gsplat_available", lambda: False)
    assert select_backend(cuda) == "reference"
    monkeypatch.setattr("dcseg.render.backend.gsplat_available", lambda: True)
    assert select_backend(cuda) == "gsplat"


def test_env_variable_routes_render(monkeypatch: pytest.MonkeyPatch) -> None:
    """DCSEG_RENDER_BACKEND=reference makes render() use the reference rasterizer."""
    calls: list[str] = []

    def spy(*args: Any) -> torch.Tensor:
        calls.append("reference")
        return composite_reference(*args)

    monkeypatch.setattr("dcseg.render.api.composite_reference", spy)
    monkeypatch.setenv(BACKEND_ENV, "reference")
    render(_gaussians([[0.0, 0.0, 2.0]], -2.0, 0.0), torch.ones(1, 1), scenes.camera())
    assert calls == ["reference"]


def test_gsplat_arguments_shift_principal_point() -> None:
    """gsplat puts pixel centres at +0.5: K's principal point is shifted by half a pixel."""
    g = scenes.scene(4, grad=False)
    cam = scenes.camera()
    args = _arguments(g, torch.ones(4, 3, dtype=torch.float64), cam)
    torch.testing.assert_close(args["Ks"][0, :2, 2], cam.K[:2, 2] + 0.5)
    assert args["eps2d"] == 0.3 and args["render_mode"] == "RGB+ED" and not args["packed"]
    torch.testing.assert_close(args["scales"], torch.exp(g.log_scales))


@pytest.mark.gpu
def test_gsplat_matches_reference() -> None:  # pragma: no cover - needs CUDA
    """On CUDA, gsplat and the reference agree in forward and in gradients (float32)."""
    cuda = torch.device("cuda")
    results = {}
    for backend in ("reference", "gsplat"):
        g = scenes.scene(300, seed=4, dtype=torch.float32, grad=False).to(cuda)
        params = [t.requires_grad_(True) for t in scenes.parameters(g)]
        vals = scenes.values(300, 3, dtype=torch.float32).detach().to(cuda).requires_grad_(True)
        out = render(g, vals, scenes.camera(dtype=torch.float32), backend=backend)
        loss = out.values.sum() + out.alpha.sum() + 0.1 * out.depth.sum()
        results[backend] = (out, torch.autograd.grad(loss, [*params, vals]))
    (ref, ref_grads), (gs, gs_grads) = results["reference"], results["gsplat"]
    torch.testing.assert_close(gs.values, ref.values, rtol=1e-3, atol=2e-3)
    torch.testing.assert_close(gs.alpha, ref.alpha, rtol=1e-3, atol=2e-3)
    for a, b in zip(ref_grads, gs_grads, strict=True):
        torch.testing.assert_close(b, a, rtol=1e-2, atol=1e-2 * float(a.abs().max()))


def test_camera_maps_points_to_its_frame_and_pixels() -> None:
    c2w = torch.eye(4, dtype=torch.float64)
    c2w[:3, :3] = torch.tensor([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # 90 deg
    c2w[:3, 3] = torch.tensor([1.0, 2.0, 0.0])
    k = torch.tensor([[100.0, 0, 50], [0, 100.0, 40], [0, 0, 1]], dtype=torch.float64)
    camera = Camera(c2w, k, 100, 80)
    points = torch.tensor([[1.0, 2.0, 2.0], [1.0, 2.2, 2.0]], dtype=torch.float64)
    cam = camera.to_camera(points)
    assert torch.allclose(cam, torch.tensor([[0.0, 0.0, 2.0], [0.2, 0.0, 2.0]], dtype=cam.dtype))
    assert torch.allclose(camera.viewmat()[:3, :3] @ points[1] + camera.viewmat()[:3, 3], cam[1])
    uv = camera.to_pixels(cam)
    assert torch.allclose(uv, torch.tensor([[50.0, 40.0], [60.0, 40.0]], dtype=uv.dtype))
