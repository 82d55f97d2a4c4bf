"""Initialisation from depth on the analytic scene."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from dcseg.reconstruct import init_from_capture
from dcseg.reconstruct.config import FAST
from dcseg.reconstruct.init import auto_voxel_size, backproject, scene_extent, voxel_downsample
from tests.dcseg.reconstruct.scene import make_capture, surface_distance


@pytest.fixture(scope="module")
def capture():
    return make_capture(frames=4, width=48, height=36)


def test_backprojected_depth_lies_on_the_surface(capture) -> None:
    points, colours = backproject(capture.frames[0])
    assert len(points) == int((capture.frames[0].depth > 0).sum())
    assert float(surface_distance(points).max()) < 1e-4
    assert colours.min() >= 0.0 and colours.max() <= 1.0


def test_init_points_are_near_the_surface(capture) -> None:
    cfg = replace(FAST, init_pixel_stride=1)
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


def test_automatic_voxel_size_is_clipped() -> None:
    assert auto_voxel_size(0.1, FAST) == FAST.voxel_min
    assert auto_voxel_size(100.0, FAST) == FAST.voxel_max
    assert math.isclose(auto_voxel_size(2.0, FAST), 0.01)
    assert auto_voxel_size(2.0, replace(FAST, voxel_size=0.2)) == 0.2
