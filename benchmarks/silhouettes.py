"""Where a render's depth edges sit against the sensor's: foreground spilled over silhouettes.

A held-out pixel of the background next to a foreground object (a sensor pixel within
``d`` px, Chebyshev, more than :data:`JUMP` nearer) is counted per ``d`` in :data:`DISTANCES`;
it is *spilled* when the render's depth there is also more than :data:`JUMP` nearer than the
sensor's: the render's silhouette lies ``d`` px or more outside the sensor's. The same is
counted for the nearest training frames' own depth warped into the view (of the pixels it
covers): how far the sensor's own silhouettes move between views. On 7-Scenes the render
spills 2-3 px where the frames' depth spills about 1 (``benchmarks/held_out_errors.py``).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

JUMP = 0.1
"""Metres nearer that make a pixel foreground (the held-out tail's threshold)."""

DISTANCES = (1, 2, 3, 4)
"""Chebyshev distances (px) from the silhouette that are counted."""


def counts(
    rendered: NDArray[Any], truth: NDArray[Any], warp: NDArray[Any] | None
) -> NDArray[np.int64]:
    """``[len(DISTANCES), 4]`` per distance: background pixels, those the render spills onto,
    those the warped depth covers, and those it spills onto (0 without ``warp``)."""
    valid = truth > 0
    far = np.where(valid, truth, np.inf)
    out = np.zeros((len(DISTANCES), 4), dtype=np.int64)
    inside = np.zeros(truth.shape, dtype=bool)  # pixels with foreground closer than d
    for i, d in enumerate(DISTANCES):
        nearest = ndimage.minimum_filter(far, size=2 * d + 1, mode="nearest")
        within = valid & (nearest < truth - JUMP)
        ring = within & ~inside
        inside |= within
        out[i, 0] = ring.sum()
        out[i, 1] = (ring & (rendered < truth - JUMP)).sum()
        if warp is not None:
            covered = ring & (warp > 0)
            out[i, 2] = covered.sum()
            out[i, 3] = (covered & (warp < truth - JUMP)).sum()
    return out


def summary(total: NDArray[np.int64]) -> dict[str, dict[str, float | int | None]]:
    """Per distance the background pixels and the shares the render and the warp spill onto."""
    return {
        f"{d} px": {
            "pixels": int(row[0]),
            "render_spilled": float(row[1] / row[0]) if row[0] else None,
            "warp_spilled": float(row[3] / row[2]) if row[2] else None,
        }
        for d, row in zip(DISTANCES, total, strict=True)
    }
