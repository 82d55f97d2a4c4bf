"""Procedural textures for the synthetic room: wooden floor planks and patterned wallpaper.

Generated in code from a seeded generator (no image assets), so that the walls and floor carry
enough texture for photometric reconstruction.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

TEXTURE_SIZE = 256


def _smooth_noise(rng: np.random.Generator, size: int, cells: int) -> NDArray[np.float64]:
    """Low-frequency noise in [-1, 1]: a coarse random grid upsampled bilinearly."""
    import cv2

    coarse = rng.uniform(-1.0, 1.0, size=(cells, cells)).astype(np.float32)
    return np.asarray(cv2.resize(coarse, (size, size), interpolation=cv2.INTER_LINEAR), np.float64)


def wood_floor(rng: np.random.Generator, size: int = TEXTURE_SIZE) -> NDArray[np.uint8]:
    """Planks of slightly different brown shades with grain lines, ``[size, size, 3]`` RGB."""
    base = np.array([150.0, 105.0, 65.0]) * rng.uniform(0.8, 1.15)
    rows = 16
    plank = np.repeat(rng.uniform(0.75, 1.2, size=rows), size // rows)[:size]
    y, x = np.mgrid[0:size, 0:size].astype(np.float64)
    offsets = np.repeat(rng.uniform(0, 40, size=rows), size // rows)[:size]
    grain = 0.08 * np.sin((x + offsets[:, None]) * 0.35 + 3.0 * _smooth_noise(rng, size, 6))
    shade = plank[:, None] * (1.0 + grain + 0.06 * _smooth_noise(rng, size, 24))
    shade[(y.astype(int) % (size // rows)) < 2] *= 0.55
    joints = rng.integers(0, size, size=rows)
    for r, j in enumerate(joints):
        shade[r * (size // rows) : (r + 1) * (size // rows), j : j + 2] *= 0.6
    out: NDArray[np.uint8] = np.clip(shade[..., None] * base, 0, 255).astype(np.uint8)
    return out


def wallpaper(rng: np.random.Generator, width: int, height: int) -> NDArray[np.uint8]:
    """A pastel wall with stripes, a dado band and blotches, ``[height, width, 3]`` RGB."""
    base = rng.uniform(150.0, 235.0, size=3)
    accent = base * rng.uniform(0.6, 0.85)
    y, x = np.mgrid[0:height, 0:width].astype(np.float64)
    period = float(rng.integers(6, 14))
    stripes = (np.floor(x / period) % 2 == 0).astype(np.float64)
    image = base * (1 - 0.5 * stripes[..., None]) + accent * 0.5 * stripes[..., None]
    noise = _smooth_noise(rng, max(width, height), 16)[:height, :width]
    image *= (1.0 + 0.1 * noise)[..., None]
    band = (y > height * 0.60) & (y < height * 0.64)
    image[band] = accent * 0.7
    for _ in range(int(rng.integers(4, 9))):
        cy, cx = rng.uniform(height * 0.1, height * 0.5), rng.uniform(0, width)
        r = rng.uniform(6, 20)
        spot = (y - cy) ** 2 + (x - cx) ** 2 < r * r
        image[spot] = rng.uniform(60, 200, size=3)
    out: NDArray[np.uint8] = np.clip(image, 0, 255).astype(np.uint8)
    return out
