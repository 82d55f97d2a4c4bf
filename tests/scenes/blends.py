"""Blending weights built in code: random ones, and ones listed pixel by pixel."""

from __future__ import annotations

import numpy as np
import torch

from dcseg.blend import BlendWeights


def random_blend(height: int, width: int, n: int, seed: int = 0) -> BlendWeights:
    """0-4 contributions per pixel, of ``n`` Gaussians, each weighing under 0.3."""
    g = torch.Generator().manual_seed(seed)
    counts = torch.randint(0, 5, (height * width,), generator=g)
    offsets = torch.cat([torch.zeros(1, dtype=torch.long), counts.cumsum(0)])
    nnz = int(offsets[-1])
    ids = torch.randint(0, n, (nnz,), generator=g)
    weights = torch.rand(nnz, generator=g) * 0.3
    return BlendWeights(height, width, offsets, ids, weights)


def blend_from_lists(
    height: int, width: int, entries: dict[int, list[tuple[int, float]]]
) -> BlendWeights:
    """BlendWeights from ``{pixel: [(gaussian id, weight), ...]}``."""
    counts = np.zeros(height * width, dtype=np.int64)
    ids: list[int] = []
    weights: list[float] = []
    for p in sorted(entries):
        counts[p] = len(entries[p])
        ids += [i for i, _ in entries[p]]
        weights += [w for _, w in entries[p]]
    offsets = np.concatenate([[0], np.cumsum(counts)])
    return BlendWeights(
        height,
        width,
        torch.from_numpy(offsets),
        torch.tensor(ids, dtype=torch.int64),
        torch.tensor(weights, dtype=torch.float32),
    )
