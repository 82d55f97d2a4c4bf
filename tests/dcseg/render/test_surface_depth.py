"""Surface depth: a silhouette renders its object's depth or the wall's, never between."""

from __future__ import annotations

import math

import pytest
import torch

from dcseg.gaussians import Gaussians
from dcseg.render import render, render_planar
from dcseg.render.surface_depth import surface_depth
from tests.scenes.gaussians import camera, gaussians_at, ray_plane_depth, tilted_disc


def disc_before_wall() -> Gaussians:
    """An opaque round blob 1.5 m ahead in front of a flat opaque wall at 3 m."""
    scales = torch.tensor([[0.15, 0.15, 0.15], [4.0, 4.0, 1e-6]], dtype=torch.float64).log()
    return gaussians_at(
        torch.tensor([[0.0, 0.0, 1.5], [0.0, 0.0, 3.0]], dtype=torch.float64),
        scales,
        torch.tensor([6.0, 6.0], dtype=torch.float64),
    )


def test_a_silhouette_takes_one_surface_not_a_blend() -> None:
    cam = camera(64, 48)
    scene = disc_before_wall()
    mean = render(scene, torch.ones(2, 1, dtype=torch.float64), cam, backend="cpu").depth
    first = surface_depth(scene, cam).double()
    covered = mean > 0
    blended = covered & (mean > 1.55) & (mean < 2.95)  # the blob's fuzzy rim over the wall
    assert int(blended.sum()) > 20
    on_a_surface = ((first - 1.5).abs() < 1e-4) | ((first - 3.0).abs() < 1e-4)
    assert bool(on_a_surface[covered].all())
    assert abs(float(first[24, 32]) - 1.5) < 1e-4  # the blob's centre (principal point)
    assert abs(float(first[2, 2]) - 3.0) < 1e-4  # the wall at a corner


@pytest.mark.parametrize("angle", [0.0, 50.0])
def test_planar_first_surface_is_the_ray_plane_depth(angle: float) -> None:
    cam = camera(64, 48)
    disc = tilted_disc(math.radians(angle))
    first = surface_depth(disc, cam, planar=True).double()
    alpha = render_planar(disc, torch.ones(1, 1, dtype=torch.float64), cam).alpha
    covered = alpha > 0.05
    v, u = torch.nonzero(covered, as_tuple=True)
    truth = ray_plane_depth(disc, u.double(), v.double(), cam.K)
    assert float((first[covered] - truth).abs().max()) < 1e-4  # float32 output
    assert bool((first[~(alpha > 0)] == 0).all())  # nothing rendered: no depth


def two_walls(gap: float) -> Gaussians:
    """Two half-transparent flat walls at 2 m and ``2 + gap`` m."""
    scales = torch.tensor([[4.0, 4.0, 1e-6]] * 2, dtype=torch.float64).log()
    return gaussians_at(
        torch.tensor([[0.0, 0.0, 2.0], [0.0, 0.0, 2.0 + gap]], dtype=torch.float64),
        scales,
        torch.tensor([0.0, 0.0], dtype=torch.float64),  # opacity 0.5 each
    )


def test_layers_within_the_window_blend_and_farther_ones_do_not() -> None:
    cam = camera(16, 12)
    mean = render(two_walls(0.02), torch.ones(2, 1, dtype=torch.float64), cam).depth
    close = surface_depth(two_walls(0.02), cam)  # 2 cm apart: one surface, blended
    apart = surface_depth(two_walls(0.3), cam)  # 30 cm apart: the front wall alone
    centre = (6, 8)
    assert abs(float(close[centre]) - float(mean[centre])) < 1e-4
    assert 2.0 < float(close[centre]) < 2.02
    assert abs(float(apart[centre]) - 2.0) < 1e-4
    assert abs(float(surface_depth(two_walls(0.02), cam, window=0.0)[centre]) - 2.0) < 1e-4


def test_the_threshold_and_window_are_checked() -> None:
    with pytest.raises(ValueError, match="threshold must be in"):
        surface_depth(tilted_disc(0.0), camera(8, 6), threshold=0.0)
    with pytest.raises(ValueError, match="window must be"):
        surface_depth(tilted_disc(0.0), camera(8, 6), window=-1.0)


def test_chunks_give_the_same_depth_as_one_pass(monkeypatch: pytest.MonkeyPatch) -> None:
    import dcseg.render.surface_depth as module

    cam = camera(40, 30)
    scene = disc_before_wall()
    whole = surface_depth(scene, cam, planar=True)
    monkeypatch.setattr(module, "CHUNK_PIXELS", 37)  # chunks end mid-row
    assert torch.equal(surface_depth(scene, cam, planar=True), whole)
