"""Blend weights reproduce the rasterizer's output without re-rasterising."""

from __future__ import annotations

import torch

from dcseg.render import render
from dcseg.render.blend_weights import blend_weights
from tests.scenes.gaussians import camera, scene, values


def test_render_from_weights_matches_rasterizer() -> None:
    g = scene(400, seed=3, dtype=torch.float32, grad=False)
    cam = camera(48, 36, dtype=torch.float32)
    v = values(400, 5, dtype=torch.float32).detach()
    blend = blend_weights(g, cam, min_weight=0.0, max_per_pixel=10_000)
    direct = render(g, v, cam, backend="reference")
    assert torch.allclose(blend.render(v), direct.values, atol=1e-4)
    ones = torch.ones(400, 1)
    assert torch.allclose(blend.render(ones)[..., 0], direct.alpha, atol=1e-4)


def test_truncation_bounds_storage_and_error() -> None:
    g = scene(400, seed=4, dtype=torch.float32, grad=False)
    cam = camera(48, 36, dtype=torch.float32)
    full = blend_weights(g, cam, min_weight=0.0, max_per_pixel=10_000)
    small = blend_weights(g, cam, min_weight=0.01, max_per_pixel=4)
    counts = small.offsets[1:] - small.offsets[:-1]
    assert int(counts.max()) <= 4 and small.nnz < full.nnz
    ones = torch.ones(400, 1)
    # Dropped contributions only remove weight, never add any.
    assert torch.all(small.render(ones) <= full.render(ones) + 1e-6)
    assert small.ids.dtype == torch.int32 and small.weights.dtype == torch.float32


def test_pixels_are_front_to_back() -> None:
    g = scene(200, seed=5, dtype=torch.float32, grad=False)
    cam = camera(32, 24, dtype=torch.float32)
    blend = blend_weights(g, cam, min_weight=0.0, max_per_pixel=10_000)
    z = g.means[:, 2]
    for p in range(0, 32 * 24, 37):
        ids = blend.ids[blend.offsets[p] : blend.offsets[p + 1]].long()
        assert torch.all(z[ids][1:] >= z[ids][:-1] - 1e-6)


def test_empty_scene() -> None:
    g = scene(0, grad=False, dtype=torch.float32)
    blend = blend_weights(g, camera(8, 6, dtype=torch.float32))
    assert blend.nnz == 0 and blend.offsets.shape == (49,)
