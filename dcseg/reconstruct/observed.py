"""Which pixels of a held-out frame the training frames observed.

A held-out view can look at what no training view saw (a corner at the start of a trajectory):
no reconstruction can draw it, and the raw held-out PSNR then measures the trajectory rather
than the reconstruction. Each held-out depth pixel (every :data:`GRID`-th) is back-projected and
counted as observed when some training frame sees that point: in front of it, inside its image
and not behind its depth there (:func:`dcseg.reconstruct.sharpness.sees`). Pixels without
depth cannot be checked and are left out. ``reconstruction.json`` reports the PSNR over the
observed pixels beside the raw one (``psnr_observed``, ``observed_share``).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from dcseg.reconstruct.init import backproject_points
from dcseg.reconstruct.sharpness import sees
from dcseg.types import Frame

GRID = 4
"""The check back-projects every this-many-th pixel along both axes (the rest take the nearest
checked pixel's answer): 1/16 of the pixels, ~1 ms per training frame at 640x480."""


def observed(frame: Frame, train: Sequence[Frame], grid: int = GRID) -> NDArray[np.bool_]:
    """``[H, W]``: whether each pixel of ``frame`` has depth and shows what a frame of ``train``
    saw."""
    valid = frame.depth[::grid, ::grid] > 0
    world, _ = backproject_points(frame, grid)  # the valid grid pixels, in np.nonzero order
    seen = np.zeros(len(world), dtype=bool)
    for other in train:
        seen |= sees(other, world)
    coarse = np.zeros(valid.shape, dtype=bool)
    coarse[valid] = seen
    full = np.repeat(np.repeat(coarse, grid, axis=0), grid, axis=1)
    out: NDArray[np.bool_] = full[: frame.height, : frame.width] & (frame.depth > 0)
    return out
