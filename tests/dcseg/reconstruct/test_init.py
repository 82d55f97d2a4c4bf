"""Initialisation from depth on the analytic scene."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from dcseg.reconstruct import init_from_capture
from dcseg.reconstruct.config import FAST
from dcseg.reconstruct.depth_filter import DepthFilter
from dcseg.reconstruct.init import (
    auto_voxel_size,
    backproject,
    backproject_points,
    point_cloud,
    project_points,
    scene_extent,
    voxel_downsample,
    voxel_keys,
)
from tests.scenes.analytic import make_capture, surface_distance


@pytest.fixture(scope="module")
def capture():
    return make_capture(frames=4, width=48, height=36)


def test_backprojected_depth_lies_on_the_surface(capture) -> None:
    points, colours = backproject(capture.frames[0])
    assert len(points) == int((capture.frames[0].depth > 0).sum())
    assert float(surface_distance(points).max()) < 1e-4
    assert colours.min() >= 0.0 and colours.max() <= 1.0


def test_projected_points_land_on_the_pixels_they_came_from(capture) -> None:
    frame = capture.frames[1]
    world, (u, v) = backproject_points(frame)
    x, y, z, inside = project_points(frame, world)
    assert inside.all() and (x == u).all() and (y == v).all()
    assert np.allclose(z, frame.depth[v, u], atol=1e-5)
    behind = 2.0 * frame.c2w[:3, 3] - world[:1]  # mirrored through the camera centre
    beside = world[:1] + 100.0 * frame.c2w[:3, 0]  # far off to the right
    assert not project_points(frame, np.concatenate([behind, beside]))[3].any()


def test_init_points_are_near_the_surface(capture) -> None:
    cfg = replace(FAST, init_pixel_stride=1, init_thickness=None)  # blobs: identity rotations
    gaussians = init_from_capture(capture, cfg)
    means = gaussians.means.numpy().astype(np.float64)
    # a voxel average of surface points lies within a voxel diagonal of the surface
    voxel = auto_voxel_size(scene_extent(capture.frames), cfg)
    assert float(np.median(surface_distance(means))) < 1e-3
    assert float(surface_distance(means).max()) < math.sqrt(3) * voxel
    assert gaussians.sh.shape[1:] == (1, 3)
    assert np.allclose(gaussians.opacities().numpy(), 0.3, atol=1e-6)
    assert np.array_equal(gaussians.quats.numpy()[:, 0], np.ones(len(gaussians), np.float32))
    assert np.all(np.isfinite(gaussians.log_scales.numpy()))
    colours = gaussians.colors_dc().numpy()
    assert colours.min() >= 0.0 and colours.max() <= 1.0


def test_init_respects_point_cap_and_sh_degree(capture) -> None:
    cfg = replace(FAST, init_pixel_stride=1, max_init_points=300, sh_degree=3)
    gaussians = init_from_capture(capture, cfg)
    assert 0 < len(gaussians) <= 300
    assert gaussians.sh_degree == 3
    assert float(gaussians.sh[:, 1:].abs().max()) == 0.0


def test_voxel_downsample_averages() -> None:
    points = np.array([[0.01, 0.01, 0.01], [0.03, 0.03, 0.03], [0.51, 0.0, 0.0]])
    colours = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]])
    out_p, out_c = voxel_downsample(points, colours, 0.1)
    order = np.argsort(out_p[:, 0])
    assert np.allclose(out_p[order], [[0.02, 0.02, 0.02], [0.51, 0.0, 0.0]])
    assert np.allclose(out_c[order], [[0.5, 0.0, 0.5], [0.0, 1.0, 0.0]])


def reference_voxel_downsample(
    points: np.ndarray, colours: np.ndarray, voxel: float
) -> tuple[np.ndarray, np.ndarray]:
    """The row-wise implementation ``voxel_downsample`` replaced (its test oracle)."""
    keys = np.floor(points / voxel).astype(np.int64)
    _, inverse, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    m = len(counts)
    out_p = np.stack([np.bincount(inverse, points[:, i], m) for i in range(3)], axis=1)
    out_c = np.stack([np.bincount(inverse, colours[:, i], m) for i in range(3)], axis=1)
    return out_p / counts[:, None], out_c / counts[:, None]


@pytest.mark.parametrize(
    ("seed", "centre", "spread", "voxel"),
    [
        (0, 0.0, 2.0, 0.05),  # around the origin: negative and positive cells
        (1, -40.0, 3.0, 0.01),  # all cells negative
        (2, 1e4, 50.0, 0.02),  # far from the origin
        (3, 0.0, 0.01, 0.1),  # a handful of voxels, many points each
    ],
)
def test_voxel_downsample_matches_the_row_wise_reference(seed, centre, spread, voxel) -> None:
    rng = np.random.default_rng(seed)
    points = centre + spread * rng.standard_normal((20_000, 3))
    points[:, 1] *= 3.0  # unequal spans per axis
    colours = rng.random((20_000, 3))
    expected = reference_voxel_downsample(points, colours, voxel)
    got = voxel_downsample(points, colours, voxel)
    assert voxel_keys(np.floor(points / voxel).astype(np.int64)) is not None
    for a, b in zip(got, expected, strict=True):
        assert a.dtype == b.dtype and a.shape == b.shape
        assert np.array_equal(a, b)  # bit-identical, same voxel order


def test_voxel_downsample_falls_back_when_cells_overflow_an_int64() -> None:
    rng = np.random.default_rng(4)
    points = rng.standard_normal((5_000, 3))
    points[:3] = [[-4e6, -4e6, -4e6], [4e6, 4e6, 4e6], [4e6, -4e6, 0.0]]
    colours = rng.random((5_000, 3))
    voxel = 1e-3  # cells span 8e9 per axis: 5e29 voxels do not fit in an int64
    assert voxel_keys(np.floor(points / voxel).astype(np.int64)) is None
    expected = reference_voxel_downsample(points, colours, voxel)
    got = voxel_downsample(points, colours, voxel)
    for a, b in zip(got, expected, strict=True):
        assert np.array_equal(a, b)


def test_voxel_keys_order_rows_lexicographically() -> None:
    cells = np.array([[1, -2, 3], [-1, 5, 0], [1, -2, 2], [-1, 4, 9], [0, 0, 0]], np.int64)
    keys = voxel_keys(cells)
    assert keys is not None
    assert np.array_equal(np.argsort(keys), np.lexsort(cells.T[::-1]))


def test_point_cloud_coarsens_until_the_cap_as_before(capture) -> None:
    cfg = replace(FAST, init_pixel_stride=1, max_init_points=300)
    extent = scene_extent(capture.frames)
    points, colours = point_cloud(capture.frames, cfg, extent)
    parts = [backproject(f, 1, DepthFilter.of(cfg)) for f in capture.frames]
    all_p = np.concatenate([p for p, _ in parts])
    all_c = np.concatenate([c for _, c in parts])
    voxel = auto_voxel_size(extent, cfg)
    expected = reference_voxel_downsample(all_p, all_c, voxel)
    while len(expected[0]) > cfg.max_init_points:
        voxel *= math.sqrt(len(expected[0]) / cfg.max_init_points) * 1.05
        expected = reference_voxel_downsample(all_p, all_c, voxel)
    assert np.array_equal(points, expected[0]) and np.array_equal(colours, expected[1])


def test_automatic_voxel_size_is_clipped() -> None:
    assert auto_voxel_size(0.1, FAST) == FAST.voxel_min
    assert auto_voxel_size(100.0, FAST) == FAST.voxel_max
    assert math.isclose(auto_voxel_size(2.0, FAST), 0.01)
    assert auto_voxel_size(2.0, replace(FAST, voxel_size=0.2)) == 0.2
