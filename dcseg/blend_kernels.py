"""numba kernel of :meth:`dcseg.blend.BlendWeights.dominant_group` for CPU tensors.

One pass over the stored contributions (O(nnz), parallel over pixel chunks): each chunk keeps a
dense ``[K]`` accumulator and the list of groups it touched for the current pixel, so no
``pixels x K`` table is ever built.
"""

from __future__ import annotations

from typing import Any

import numba
import numpy as np
from numba import prange

Array = Any  # numpy arrays; numba cannot see annotations, mypy cannot see numba

PIXEL_CHUNK = 2048
"""Pixels per parallel work item (each item allocates its ``[K]`` accumulator once)."""


@numba.njit(parallel=True, cache=True, nogil=True)
def dominant_group(
    offsets: Array, ids: Array, weights: Array, group: Array, n_groups: int, min_weight: float
) -> Array:
    """``[P]`` int64: per pixel, the group with the largest summed weight, -1 below the floor.

    Args:
        offsets: ``[P + 1]`` CSR offsets over pixels.
        ids: ``[nnz]`` Gaussian index of each contribution.
        weights: ``[nnz]`` blending weight of each contribution.
        group: ``[N]`` int64 group of every Gaussian, -1 = none.
        n_groups: number of groups K (every ``group`` value is below it).
        min_weight: smallest summed weight that claims a pixel (and it must be > 0), rounded
            to the weights' precision by the caller.

    Ties go to the lower group index.
    """
    n_pixels = offsets.shape[0] - 1
    out = np.full(n_pixels, -1, dtype=np.int64)
    for chunk in prange((n_pixels + PIXEL_CHUNK - 1) // PIXEL_CHUNK):
        acc = np.zeros(n_groups, dtype=weights.dtype)  # sums in the weights' precision
        stamp = np.full(n_groups, -1, dtype=np.int64)  # last pixel that touched each group
        touched = np.empty(n_groups, dtype=np.int64)
        for p in range(chunk * PIXEL_CHUNK, min(n_pixels, (chunk + 1) * PIXEL_CHUNK)):
            n_touched = 0
            for k in range(offsets[p], offsets[p + 1]):
                g = group[ids[k]]
                if g < 0:
                    continue
                if stamp[g] != p:
                    stamp[g] = p
                    acc[g] = 0.0
                    touched[n_touched] = g
                    n_touched += 1
                acc[g] += weights[k]
            best, winner = 0.0, -1
            for t in range(n_touched):
                g = touched[t]
                if acc[g] > best or (acc[g] == best and winner >= 0 and g < winner):
                    best, winner = acc[g], g
            if winner >= 0 and best >= min_weight:
                out[p] = winner
    return out


@numba.njit(cache=True, nogil=True)
def add_class_agreement(
    offsets: Array,
    ids: Array,
    weights: Array,
    pixel_class: Array,
    gaussian_class: Array,
    agree: Array,
    total: Array,
) -> None:
    """Add one view's class evidence per Gaussian into ``agree`` and ``total`` (in place).

    For every contribution of a pixel with a class (``pixel_class >= 0``), its weight goes to
    its Gaussian's ``total``, and also to ``agree`` when the pixel's class is the Gaussian's
    ``gaussian_class``. Serial: one O(nnz) pass, accumulated in float64.
    """
    for p in range(offsets.shape[0] - 1):
        c = pixel_class[p]
        if c < 0:
            continue
        for k in range(offsets[p], offsets[p + 1]):
            g = ids[k]
            w = np.float64(weights[k])
            total[g] += w
            if gaussian_class[g] == c:
                agree[g] += w


@numba.njit(cache=True, nogil=True)
def add_class_evidence(
    offsets: Array, ids: Array, weights: Array, pixel_class: Array, evidence: Array
) -> None:
    """Add one view's blending weight per Gaussian and pixel class into ``evidence`` ``[N, C]``.

    Every contribution of a pixel with a class ``c >= 0`` adds its weight to
    ``evidence[gaussian, c]``. Serial: one O(nnz) pass, accumulated in float64.
    """
    for p in range(offsets.shape[0] - 1):
        c = pixel_class[p]
        if c < 0:
            continue
        for k in range(offsets[p], offsets[p + 1]):
            evidence[ids[k], c] += np.float64(weights[k])
