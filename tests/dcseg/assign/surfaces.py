"""Hand-made surfaces of Gaussian centres for the object tests (adoption, planes, instances)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

SPACING = 0.02
RADIUS = 3 * SPACING
WALL, FLOOR, DUCK, MUG = 0, 1, 2, 3
N_CLASSES = 4
STUFF = (WALL, FLOOR)


def patch(x0: float, x1: float, y0: float, y1: float, z: float = 0.0) -> NDArray[np.float64]:
    """A flat grid of Gaussian centres at ``SPACING`` (a surface)."""
    xs = np.arange(x0, x1, SPACING)
    ys = np.arange(y0, y1, SPACING)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    return np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, z)], axis=1)


def unit(*values: float) -> NDArray[np.float32]:
    v = np.array(values, dtype=np.float32)
    return v / np.linalg.norm(v)


def corner(noise: float = 0.0) -> NDArray[np.float64]:
    """One wall along y = 0 and one along x = 0, meeting at the z axis, as one point set."""
    flat = patch(0, 0.8, 0, 0.6)
    wall_x = np.stack([flat[:, 0] + SPACING, np.zeros(len(flat)), flat[:, 1]], axis=1)
    wall_y = np.stack([np.zeros(len(flat)), flat[:, 0] + SPACING, flat[:, 1]], axis=1)
    points = np.concatenate([wall_x, wall_y])
    return points + np.random.default_rng(0).normal(0.0, noise, points.shape)
