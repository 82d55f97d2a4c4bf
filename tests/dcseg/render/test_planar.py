"""Planar depth: a tilted disc renders the depth of its plane, not its centre's, everywhere."""

from __future__ import annotations

import math

import pytest
import torch
from torch import Tensor

from dcseg.gaussians import Gaussians
from dcseg.render import render, render_planar
from dcseg.render.planar import depth_planes, planes_reference
from tests.scenes.gaussians import (
    camera,
    parameters,
    ray_plane_depth,
    scene,
    tilted_disc,
    values,
)


@pytest.mark.parametrize("backend", ["reference", "cpu"])
def test_a_tilted_disc_renders_its_plane(backend: str) -> None:
    cam = camera(64, 48)
    disc = tilted_disc(math.radians(50))
    colour = torch.ones(1, 3, dtype=torch.float64)
    plain = render(disc, colour, cam, backend=backend)
    planar = render_planar(disc, colour, cam, backend=backend)
    covered = planar.alpha > 0.5
    v, u = torch.nonzero(covered, as_tuple=True)
    truth = ray_plane_depth(disc, u.double(), v.double(), cam.K)
    planar_error = (planar.depth[covered] - truth).abs()
    plain_error = (plain.depth[covered] - truth).abs()
    assert plain_error.mean() > 0.1  # the centre's depth over a 50-degree slope
    assert planar_error.max() < 1e-6
    assert torch.allclose(planar.values, plain.values) and torch.allclose(planar.alpha, plain.alpha)


def test_a_round_gaussian_keeps_its_centre_depth() -> None:
    cam = camera(64, 48)
    blob = tilted_disc(math.radians(50), thickness=0.4)
    planes = depth_planes(blob, cam)
    assert torch.allclose(planes[:, 1:], torch.zeros(1, 2, dtype=torch.float64))
    assert torch.allclose(planes[:, 0], 1.0 / blob.means[:, 2])


def test_an_edge_on_plane_has_a_capped_slope() -> None:
    cam = camera(64, 48)
    planes = depth_planes(tilted_disc(math.radians(90)), cam)
    assert torch.isfinite(planes).all()
    assert float(planes[0, 1].abs()) <= 5.0 / (2.0 * float(cam.K[0, 0])) + 1e-9


def test_planar_depth_is_differentiable_in_every_parameter() -> None:
    cam = camera()
    gaussians = scene(12)
    out = render_planar(gaussians, values(12, 3), cam, backend="reference")
    (out.depth * out.alpha).sum().backward()  # type: ignore[no-untyped-call]
    grads = [p.grad for p in parameters(gaussians)]
    assert all(g is not None and torch.isfinite(g).all() and g.abs().sum() > 0 for g in grads)


def test_planar_depth_matches_between_backends() -> None:
    cam = camera()
    gaussians = scene(30, grad=False)
    ref = render_planar(gaussians, values(30, 3).detach(), cam, backend="reference")
    cpu = render_planar(gaussians, values(30, 3).detach(), cam, backend="cpu")
    assert torch.allclose(ref.depth, cpu.depth, atol=1e-6)


def awkward_scene(dtype: torch.dtype) -> Gaussians:
    """Random Gaussians plus the planes' edge cases: behind the camera, seen edge-on (capped
    slope), a plane through the camera centre (zero slope denominator), a round disc."""
    base = scene(60, dtype=dtype, grad=False)
    extra_means = torch.tensor(
        [[0.2, 0.1, -1.0], [0.3, 0.0, 2.0], [0.0, 0.0, 2.0], [0.1, 0.1, 3.0]], dtype=dtype
    )
    edge_on = [math.cos(math.pi / 4), 0.0, math.sin(math.pi / 4), 0.0]
    extra_quats = torch.tensor(
        [[1.0, 0.2, 0.0, 0.0], edge_on, edge_on,
         [0.9, 0.1, 0.3, 0.0]], dtype=dtype,
    )  # fmt: skip
    extra_scales = torch.tensor(
        [[0.1, 0.1, 0.001], [0.2, 0.2, 1e-5], [0.2, 0.3, 1e-4], [0.05, 0.05, 0.01]], dtype=dtype
    ).log()
    tensors = [
        torch.cat([base.means, extra_means]),
        torch.cat([base.quats, extra_quats]),
        torch.cat([base.log_scales, extra_scales]),
    ]
    means, quats, log_scales = (t.clone().requires_grad_(True) for t in tensors)
    n = means.shape[0]
    return Gaussians(
        means, quats, log_scales, torch.zeros(n, dtype=dtype), base.sh[:1].expand(n, 1, 3)
    )


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_the_cpu_kernels_compute_the_reference_planes_and_gradients(dtype: torch.dtype) -> None:
    cam = camera(dtype=dtype)
    turn = torch.tensor(math.radians(20), dtype=dtype)  # a camera that is not the world frame
    cam.c2w[:3, :3] = torch.tensor(
        [[math.cos(turn), 0, math.sin(turn)], [0, 1, 0], [-math.sin(turn), 0, math.cos(turn)]],
        dtype=dtype,
    )
    cam.c2w[:3, 3] = torch.tensor([0.1, -0.05, 0.2], dtype=dtype)
    gaussians = awkward_scene(dtype)
    ref = planes_reference(gaussians, cam)
    cpu = depth_planes(gaussians, cam, backend="cpu")
    tolerance = 1e-12 if dtype == torch.float64 else 1e-5
    assert torch.allclose(cpu, ref, rtol=tolerance, atol=tolerance)
    assert float(ref[-3:, 1:].detach().abs().max()) > 0  # the edge cases are not all flat
    weights = torch.randn(ref.shape, generator=torch.Generator().manual_seed(3), dtype=dtype)
    inputs = [gaussians.means, gaussians.quats, gaussians.log_scales]
    expected = torch.autograd.grad((ref * weights).sum(), inputs)
    got = torch.autograd.grad((cpu * weights).sum(), inputs)
    for name, want, have in zip(("means", "quats", "log_scales"), expected, got, strict=True):
        scale = float(want.abs().max())
        assert torch.allclose(have, want, rtol=tolerance, atol=tolerance * scale), name


def test_the_cpu_planes_pass_gradcheck() -> None:
    cam = camera()
    gaussians = awkward_scene(torch.float64)
    # not the Gaussian behind the camera (1 / 1e-6 is too steep for finite differences) nor
    # the round disc (which of two equal scales is the middle one is arbitrary: a kink)
    smooth = [*range(60), 61, 62]
    inputs = tuple(
        t.detach()[smooth].requires_grad_(True)
        for t in (gaussians.means, gaussians.quats, gaussians.log_scales)
    )

    def planes(means: Tensor, quats: Tensor, log_scales: Tensor) -> Tensor:
        moved = Gaussians(
            means, quats, log_scales, torch.zeros(62, dtype=torch.float64), gaussians.sh[smooth]
        )
        return depth_planes(moved, cam, backend="cpu")

    assert torch.autograd.gradcheck(planes, inputs, eps=1e-7, atol=1e-5)
