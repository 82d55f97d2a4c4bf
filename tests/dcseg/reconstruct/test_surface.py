"""Surface priors: disc frames from neighbours, the thickness and centre-depth terms, and a fit
whose centres end nearer the true surfaces with the priors than without."""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np
import pytest
import torch

from dcseg.gaussians import Gaussians
from dcseg.reconstruct.config import FAST, ReconstructConfig
from dcseg.reconstruct.evaluate import evaluate
from dcseg.reconstruct.fit import optimise
from dcseg.reconstruct.init import init_from_frames, scene_extent
from dcseg.reconstruct.surface import (
    OPACITY_FLOOR,
    centre_depth_grad,
    disc_frames,
    opacity_grad,
    thickness_grad,
)
from dcseg.reconstruct.views import make_view
from dcseg.render import Camera
from dcseg.render.projection import scaled_rotations
from tests.scenes.analytic import make_capture, surface_distance


def _rotations(quats: np.ndarray) -> torch.Tensor:
    q = torch.as_tensor(quats, dtype=torch.float64)
    return scaled_rotations(q, torch.zeros(len(q), 3, dtype=torch.float64))


def test_disc_frames_put_the_normal_last_and_the_spread_in_the_plane() -> None:
    rng = np.random.default_rng(0)
    points = np.zeros((400, 3))
    points[:, 0] = rng.uniform(-1.0, 1.0, 400)
    points[:, 1] = rng.uniform(-0.3, 0.3, 400)  # wider along x than along y
    quats, spread = disc_frames(points)
    axes = _rotations(quats).numpy()
    assert np.allclose(np.abs(axes[:, :, 2]), [0.0, 0.0, 1.0], atol=1e-6)  # normal = +-z
    assert np.allclose(np.linalg.det(axes), 1.0)
    assert np.all(spread[:, 2] < 1e-9) and np.all(spread[:, 0] >= spread[:, 1])


def test_disc_frames_of_too_few_points_are_identity() -> None:
    quats, spread = disc_frames(np.zeros((3, 3)))
    assert np.array_equal(quats, np.tile([1.0, 0.0, 0.0, 0.0], (3, 1)))
    assert np.array_equal(spread, np.ones((3, 3)))


def test_thickness_grad_is_the_gradient_of_the_mean_smallest_scale() -> None:
    log_scales = torch.log(torch.tensor([[0.1, 0.02, 0.3], [0.5, 0.5, 0.04], [0.2, 0.3, 0.25]]))
    leaf = log_scales.clone().requires_grad_(True)
    term = leaf.min(dim=1).values.exp().mean()  # the term: 0.02 + 0.04 + 0.2, over 3
    (expected,) = torch.autograd.grad(term, leaf)
    grad = thickness_grad(log_scales)
    assert torch.allclose(grad, expected)
    assert float(grad[0, 1]) == pytest.approx(0.02 / 3) and int((grad != 0).sum()) == 3


def test_opacity_grad_is_the_gradient_of_the_mean_transparency_above_the_floor() -> None:
    logits = torch.logit(torch.tensor([0.05, 0.2, 0.3, 0.5, 0.9]))
    leaf = logits.clone().requires_grad_(True)
    opacity = torch.sigmoid(leaf)
    term = torch.where(opacity.detach() > OPACITY_FLOOR, 1.0 - opacity, 0.0).sum() / 5
    (expected,) = torch.autograd.grad(term, leaf)
    grad = opacity_grad(logits)
    assert torch.allclose(grad, expected)
    assert torch.equal(grad[:2], torch.zeros(2))  # at most the floor: left to the images
    assert bool((grad[2:] < 0).all())  # a descent step makes them more opaque
    assert float(grad[3]) == pytest.approx(-0.25 / 5)


def _camera(width: int = 8, height: int = 6) -> Camera:
    k = torch.tensor([[10.0, 0.0, 3.5], [0.0, 10.0, 2.5], [0.0, 0.0, 1.0]])
    return Camera(torch.eye(4), k, width, height)  # at the origin, looking along +z


def _turned_camera() -> Camera:
    """:func:`_camera` turned 30 degrees about y and moved: the view axis is not world z."""
    c2w = torch.eye(4)
    angle = math.radians(30)
    c2w[:3, :3] = torch.tensor(
        [[math.cos(angle), 0.0, math.sin(angle)], [0.0, 1.0, 0.0],
         [-math.sin(angle), 0.0, math.cos(angle)]]
    )  # fmt: skip
    c2w[:3, 3] = torch.tensor([0.3, 0.1, -0.2])
    return Camera(c2w, _camera().K, 8, 6)


def _centre_term(means: torch.Tensor, camera: Camera, depth: torch.Tensor, band: float) -> Any:
    """The centre-depth term written with autograd: the oracle of its gradient."""
    cam = camera.to_camera(means)
    z = cam[:, 2]
    u, v = torch.round(camera.to_pixels(cam.detach())).long().unbind(1)
    inside = (z > 1e-6) & (u >= 0) & (u < camera.width) & (v >= 0) & (v < camera.height)
    seen = torch.zeros_like(z)
    seen[inside] = depth[v[inside], u[inside]]
    near = inside & (seen > 0) & ((z - seen).abs() < band)
    return (z[near] - seen[near]).abs().mean(), near


def test_centre_depth_grad_pulls_the_centres_near_the_observed_depth() -> None:
    depth = torch.full((6, 8), 2.0)
    depth[0, 0] = 0.0  # invalid pixel
    means = torch.tensor(
        [
            [0.0, 0.0, 2.03],  # 3 cm behind the surface: counted
            [0.0, 0.0, 1.99],  # 1 cm in front: counted
            [0.0, 0.0, 3.0],  # another surface, occluded here: not counted
            [-0.7, -0.5, 2.0],  # projects onto the invalid pixel (0, 0): not counted
            [50.0, 0.0, 2.0],  # outside the view
            [0.0, 0.0, -2.0],  # behind the camera
            [float("nan"), 0.0, 2.0],  # not a number
        ]
    )
    grad = centre_depth_grad(means, _camera(), depth, band=0.1)
    assert torch.allclose(grad[:2], torch.tensor([[0.0, 0.0, 0.5], [0.0, 0.0, -0.5]]))
    assert torch.all(grad[2:] == 0)  # both counted centres pulled onto the surface, no other


def test_centre_depth_grad_is_the_gradient_of_the_term_from_any_pose() -> None:
    camera = _turned_camera()
    gen = torch.Generator().manual_seed(0)
    depth = 1.5 + torch.rand(6, 8, generator=gen)
    pixels = torch.rand(200, 2, generator=gen) * torch.tensor([8.0, 6.0]) - 0.5
    z = 1.5 + 1.2 * torch.rand(200, generator=gen)
    rays = torch.cat([(pixels - camera.K[:2, 2]) / camera.K[[0, 1], [0, 1]], torch.ones(200, 1)], 1)
    means = (rays * z[:, None]) @ camera.c2w[:3, :3].T + camera.c2w[:3, 3]
    leaf = means.clone().requires_grad_(True)
    term, near = _centre_term(leaf, camera, depth, band=0.3)
    (expected,) = torch.autograd.grad(term, leaf)
    assert 20 < int(near.sum()) < 200  # some counted, some not
    assert torch.allclose(centre_depth_grad(means, camera, depth, band=0.3), expected, atol=1e-6)


def test_centre_depth_grad_without_counted_centres_is_zero() -> None:
    means = torch.tensor([[0.0, 0.0, 5.0]])
    grad = centre_depth_grad(means, _camera(), torch.full((6, 8), 2.0), band=0.1)
    assert grad.shape == (1, 3) and torch.all(grad == 0)


def test_centre_depth_grad_behind_band_spares_the_far_side_of_an_object() -> None:
    depth = torch.full((6, 8), 2.0)
    means = torch.tensor([[0.0, 0.0, 2.03], [0.0, 0.0, 1.97], [0.0, 0.0, 2.005]])
    grad = centre_depth_grad(means, _camera(), depth, band=0.1, behind=0.01)
    # 3 cm behind the near surface (the far side of a small object): not counted; 3 cm in
    # front and 5 mm behind: counted, pulled onto it
    assert torch.allclose(grad, torch.tensor([[0.0, 0.0, 0.0], [0.0, 0.0, -0.5], [0, 0, 0.5]]))


def test_centre_depth_grad_window_takes_the_nearest_observed_depth() -> None:
    depth = torch.full((6, 8), 2.0)  # the background
    depth[2:5, 4:7] = 1.0  # an object whose silhouette is next to pixel (3, 3)
    depth[2, 3] = 0.0  # a dropped edge pixel: ignored
    means = torch.tensor([[-0.05, 0.05, 1.02]])  # on the object's edge, projects to (3, 3)
    one = centre_depth_grad(means, _camera(), depth, band=1.5, behind=0.05)
    three = centre_depth_grad(means, _camera(), depth, band=1.5, behind=0.05, window=3)
    assert torch.allclose(one, torch.tensor([[0.0, 0.0, -1.0]]))  # its pixel: the background
    assert torch.allclose(three, torch.tensor([[0.0, 0.0, 1.0]]))  # the window: the object
    with pytest.raises(ValueError, match="window"):
        centre_depth_grad(means, _camera(), depth, band=1.5, window=2)


def test_centre_depth_grad_window_target_is_the_mean_of_the_nearest_surface() -> None:
    depth = torch.full((6, 8), 3.0)  # a far wall
    depth[1:6, 1:6] = torch.tensor([1.00, 1.01, 1.02, 1.03, 1.04]).repeat(5, 1)  # noisy near
    z = torch.tensor([1.005, 1.025])
    means = torch.stack([-0.05 * z, torch.zeros(2), z], 1)  # both project to pixel (3, 2)
    grad = centre_depth_grad(means, _camera(), depth, band=0.5, behind=0.1, window=5)
    # the window's near depths average 1.02 (the wall's 3.0 is another surface): the
    # centre in front is pulled back, the one behind forward; nearest-depth targets would
    # leave both where they are (1.00 / 1.02 and 1.03 are within 5 mm)
    assert torch.allclose(grad, torch.tensor([[0.0, 0.0, -0.5], [0.0, 0.0, 0.5]]))


def test_centre_depth_grad_defaults_are_the_pixel_and_a_symmetric_band() -> None:
    camera = _turned_camera()
    gen = torch.Generator().manual_seed(1)
    depth = 1.5 + torch.rand(6, 8, generator=gen)
    means = camera.c2w[:3, 3] + torch.randn(300, 3, generator=gen) + camera.c2w[:3, 2] * 2.0
    base = centre_depth_grad(means, camera, depth, band=0.3)
    same = centre_depth_grad(means, camera, depth, band=0.3, behind=0.3, window=1)
    assert torch.equal(base, same) and bool((base != 0).any())


@pytest.mark.parametrize(
    "field, value",
    [("init_thickness", 0.0), ("init_thickness", 1.5), ("thickness_weight", -1.0),
     ("centre_weight", -0.1), ("centre_band", -1.0), ("centre_behind", -1.0),
     ("centre_window", 2), ("centre_window", 0), ("centre_from", -1), ("opacity_weight", -1.0)],
)  # fmt: skip
def test_config_rejects_bad_surface_values(field: str, value: float) -> None:
    with pytest.raises(ValueError, match=field):
        replace(ReconstructConfig(), **{field: value})  # type: ignore[arg-type]


PRIORS: dict[str, Any] = {"init_thickness": 0.1, "thickness_weight": 1.0, "centre_weight": 10.0}


def _fit_from_displaced(cfg: ReconstructConfig) -> tuple[float, float]:
    """Median surface distance of the opaque centres and median smallest scale after a fit that
    starts with every centre displaced ~2 cm off the analytic scene's surfaces."""
    fitted = _fitted_from_displaced(cfg)
    opaque = fitted.opacities() > 0.1
    distance = surface_distance(fitted.means[opaque].double().numpy())
    thickness = fitted.log_scales.min(dim=1).values.exp()
    return float(np.median(distance)), float(thickness.median())


def _fitted_from_displaced(cfg: ReconstructConfig) -> Gaussians:
    capture = make_capture(4, 32, 24)
    frames = capture.frames
    extent = scene_extent(frames)
    init = init_from_frames(frames, cfg, extent=extent)
    generator = torch.Generator().manual_seed(0)
    offset = 0.02 * torch.randn(init.means.shape, generator=generator)
    init = replace(init, means=init.means + offset)
    views = [make_view(f) for f in frames]
    return optimise(init, views, cfg, extent).gaussians


SMALL = replace(
    FAST, iterations=60, train_downscale=1, full_res_from=None, init_pixel_stride=1,
    densify_until=0, means_lr_init=2e-3, means_lr_final=2e-3, max_init_points=3000,
    init_thickness=None, thickness_weight=0.0, centre_weight=0.0, opacity_weight=0.0,  # blobs
)  # fmt: skip


def test_the_pull_starts_after_densification_by_default() -> None:
    """Discs, thin and pulled onto the surfaces by default, from the end of densification
    (earlier, the pull leaves small objects few opaque Gaussians)."""
    for preset in (FAST, ReconstructConfig()):
        assert preset.init_thickness == 0.1 and preset.centre_weight == 10.0
        assert preset.centre_from is None and preset.pull_start == preset.densify_until
        assert preset.opacity_weight == 0.1  # the opacity term from the same step
    assert replace(FAST, centre_from=0).pull_start == 0


def test_surface_priors_pull_centres_onto_the_surfaces_and_flatten_them() -> None:
    base = SMALL
    plain = _fit_from_displaced(base)
    priors = _fit_from_displaced(replace(base, **PRIORS))
    assert priors[0] < 0.5 * plain[0], (priors, plain)
    assert priors[1] < 0.2 * plain[1], (priors, plain)
    assert math.isfinite(priors[0])


def test_centre_pull_starts_at_centre_from() -> None:
    """No pull before ``centre_from``: starting it after the last step is no pull at all;
    starting it halfway pulls less than from the start."""
    discs = replace(SMALL, **{**PRIORS, "centre_weight": 0.0})
    off = _fitted_from_displaced(replace(SMALL, **PRIORS, centre_from=SMALL.iterations))
    assert torch.equal(off.means, _fitted_from_displaced(discs).means)
    start = _fit_from_displaced(replace(SMALL, **PRIORS))[0]
    half = _fit_from_displaced(replace(SMALL, **PRIORS, centre_from=SMALL.iterations // 2))[0]
    none = _fit_from_displaced(discs)[0]
    assert start < half < none, (start, half, none)


def test_opacity_term_makes_the_half_transparent_surface_discs_opaque() -> None:
    """On the analytic scene the discs fitted without the term are mostly half transparent
    (median ~0.2); with it, more than twice as many end above 0.5."""
    discs = replace(SMALL, **PRIORS)
    plain = _fitted_from_displaced(discs).opacities().reshape(-1)
    pushed = _fitted_from_displaced(replace(discs, opacity_weight=0.1)).opacities().reshape(-1)
    assert len(pushed) == len(plain)
    share = float((pushed > 0.5).float().mean()), float((plain > 0.5).float().mean())
    assert share[0] > 2 * share[1], share


def test_planar_depth_of_flat_gaussians_follows_the_slanted_floor() -> None:
    fitted = _fitted_from_displaced(replace(SMALL, **PRIORS, planar_depth=True))
    views = [make_view(f) for f in make_capture(4, 32, 24).frames]
    planar = evaluate(fitted, views, "cpu", planar=True).depth_mae
    centre = evaluate(fitted, views, "cpu").depth_mae
    assert planar < 0.8 * centre, (planar, centre)
