import numpy as np
import pytest

from dcseg.affinity import mask_scales
from dcseg.affinity.scales import erode
from tests.scenes.affinity import camera_matrix, encode


def test_flat_square_matches_analytic_scale():
    h = w = 200
    focal, z, n = 100.0, 2.0, 100  # n x n pixels at 2 m: side a = n z / f = 2 m
    dense = np.zeros((1, h, w), dtype=bool)
    dense[0, 50 : 50 + n, 50 : 50 + n] = True
    depth = np.full((h, w), z, dtype=np.float32)
    (scale,) = mask_scales(encode(dense), depth, camera_matrix(h, w, focal))
    side = n * z / focal
    analytic = np.sqrt(2.0) * 2.0 * side / np.sqrt(12.0)  # ||(2 std_x, 2 std_y, 0)||
    assert scale == pytest.approx(analytic, rel=1e-2)
    discrete = np.sqrt(2.0) * 2.0 * (z / focal) * np.sqrt((n * n - 1) / 12.0)
    assert scale == pytest.approx(discrete, rel=2e-3)  # only the 4 corners are eroded


def test_scale_grows_with_depth_and_ignores_invalid_depth():
    dense = np.zeros((1, 60, 80), dtype=bool)
    dense[0, 10:40, 20:60] = True
    k = camera_matrix(60, 80, 50.0)
    near = mask_scales(encode(dense), np.full((60, 80), 1.0, np.float32), k)[0]
    far = mask_scales(encode(dense), np.full((60, 80), 3.0, np.float32), k)[0]
    assert far == pytest.approx(3 * near, rel=1e-5)
    holes = np.full((60, 80), 1.0, np.float32)
    holes[:, :40] = 0.0  # left half invalid: only the right half of the box counts
    half = mask_scales(encode(dense), holes, k)[0]
    assert 0 < half < near


def test_too_few_points_give_nan():
    dense = np.zeros((2, 30, 30), dtype=bool)
    dense[0, 5:7, 5:7] = True  # 2x2: nothing survives the erosion
    dense[1, 10:20, 10:20] = True
    depth = np.ones((30, 30), np.float32)
    depth[10:20, 10:20] = 0.0  # no valid depth under mask 1
    scales = mask_scales(encode(dense), depth, camera_matrix(30, 30, 30.0))
    assert np.isnan(scales).all() and scales.dtype == np.float32


def test_erosion_is_a_majority_filter():
    mask = np.zeros((9, 9), dtype=bool)
    mask[2:5, 2:5] = True
    mask[8, :] = True  # a one-pixel line along the border vanishes
    out = erode(mask)
    expected = np.zeros((9, 9), dtype=bool)
    expected[2:5, 2:5] = True
    expected[[2, 2, 4, 4], [2, 4, 2, 4]] = False  # corners see only 4 of 9
    np.testing.assert_array_equal(out, expected)


def test_depth_at_another_resolution_is_resampled():
    dense = np.zeros((1, 40, 60), dtype=bool)
    dense[0, 5:35, 10:50] = True
    k = camera_matrix(40, 60, 40.0)
    same = mask_scales(encode(dense), np.full((40, 60), 2.0, np.float32), k)[0]
    k2 = k.copy()
    k2[:2] *= 2.0
    k2[0, 2], k2[1, 2] = (120 - 1) / 2, (80 - 1) / 2
    double = mask_scales(encode(dense), np.full((80, 120), 2.0, np.float32), k2)[0]
    assert double == pytest.approx(same, rel=1e-6)
