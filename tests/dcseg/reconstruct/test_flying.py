"""Flying pixels at depth edges: found in 1- and 2-pixel strips, nothing else, and dropped."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from dcseg.reconstruct.depth_filter import DepthFilter
from dcseg.reconstruct.flying import JUMP, drop_flying, flying_mask, flying_share
from tests.dcseg.reconstruct.test_depth_noise import room, sensor


def boxed() -> NDArray[np.float64]:
    """:func:`room` with its box 0.6 m away, well in front of the wall."""
    depth = room()
    depth[50:125, 100:200] = 0.6
    return depth


def mixed(depth: NDArray[np.float64]) -> NDArray[np.float64]:
    """The box's left edge with a one-pixel strip of mixed depth, its right edge with two."""
    out = depth.copy()
    out[50:125, 99] = 0.5 * (depth[50:125, 98] + 0.6)
    out[50:125, 200] = 0.67 * 0.6 + 0.33 * depth[50:125, 201]
    out[50:125, 201] = 0.33 * 0.6 + 0.67 * depth[50:125, 202]
    return out


def strips() -> NDArray[np.bool_]:
    truth = np.zeros((240, 320), bool)
    truth[50:125, 99] = truth[50:125, 200:202] = True
    return truth


def test_clean_edges_and_slopes_have_no_flying_pixels() -> None:
    for a in (0.0, 0.003):
        mask, edges = flying_mask(sensor(boxed(), a, 0.001), a, 0.001)
        assert edges > 300  # the box's and the hole's outlines are depth edges
        assert not mask.any()


def test_steep_slopes_are_not_edges() -> None:
    u = np.arange(200, dtype=np.float64)
    depth = np.tile(1.0 / (1.0 / 0.5 - 0.0099 * u), (20, 1)).astype(np.float32)  # grazing
    assert (np.diff(depth[0]) / depth[0, :-1] > 2 * JUMP).sum() > 5  # steps above an edge's
    mask, edges = flying_mask(depth, 0.0, 0.0)
    assert edges > 0 and not mask.any()


def test_mixed_strips_are_found_whatever_their_width() -> None:
    for a in (0.0, 0.003):
        mask, _ = flying_mask(sensor(mixed(boxed()), a, 0.001), a, 0.001)
        truth = strips()
        assert mask[truth].mean() > 0.95
        assert not mask[~truth].any()
        flying, edges = flying_share(sensor(mixed(boxed()), a, 0.001), a, 0.001)
        assert flying == mask.sum() and edges > flying


def test_flying_pixels_are_dropped_before_back_projection() -> None:
    depth = sensor(mixed(boxed()), 0.0, 0.001)
    dropped = drop_flying(depth)
    assert np.all(dropped[strips()] == 0.0)
    np.testing.assert_array_equal(dropped[~strips()], depth[~strips()])
    grid = DepthFilter(window=1, flying=True).grid(depth, 1)
    np.testing.assert_array_equal(grid, dropped)
    kept = DepthFilter(window=1, flying=False).grid(depth, 1)
    np.testing.assert_array_equal(kept, depth)
