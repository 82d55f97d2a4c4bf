"""numba kernels of the affinity stage on the CPU: KNN smoothing (forward and analytic
backward), the ground-truth pair affinity and the contrastive loss's fused per-pair passes.

The PyTorch expression ``normalize(features)[neighbours].mean(1)`` gathers an ``[R, k, D]``
tensor and runs half a dozen elementwise passes over it, forward and backward; per training
step (R ~ 17k Gaussians, k = 8, D = 32) that was ~55 ms of a ~200 ms step. These kernels read
each neighbour's feature once and never materialise the gather.

Private module; :class:`NeighbourMean` in :mod:`dcseg.affinity.knn`,
:func:`dcseg.affinity.targets.pair_affinity` and :func:`dcseg.affinity.loss.contrastive_loss`
are the public faces.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, TypeVar, cast

import numba
import numpy as np
from numba import prange

_F = TypeVar("_F", bound=Callable[..., Any])
Array = Any  # numpy arrays; numba cannot see annotations, mypy cannot see numba


def _jit(parallel: bool) -> Callable[[_F], _F]:
    return cast(Callable[[_F], _F], numba.njit(parallel=parallel, cache=True, nogil=True))


@_jit(parallel=False)
def _squared_norm(features: Array, i: int) -> float:
    """``|features[i]|^2``."""
    s = 0.0
    for d in range(features.shape[1]):
        s += features[i, d] * features[i, d]
    return s


@_jit(parallel=True)
def neighbour_mean(features: Array, neighbours: Array, eps: float) -> Array:
    """``[R, D]``: row r is the mean over j of ``features[neighbours[r, j]] / max(|.|, eps)``."""
    rows, k = neighbours.shape
    out = np.zeros((rows, features.shape[1]), dtype=features.dtype)
    for r in prange(rows):
        for j in range(k):
            i = neighbours[r, j]
            scale = 1.0 / (max(math.sqrt(_squared_norm(features, i)), eps) * k)
            for d in range(features.shape[1]):
                out[r, d] += features[i, d] * scale
    return out


@_jit(parallel=False)
def neighbour_mean_backward(
    features: Array, neighbours: Array, grad_out: Array, eps: float
) -> Array:
    """``[N, D]`` gradient of ``sum(grad_out * neighbour_mean(features, neighbours))``.

    With ``n = x / max(|x|, eps)``: ``dn^T g = (g - n (n . g)) / |x|`` where ``|x| > eps``,
    else ``g / eps`` (the clamp is constant there). Sequential: many rows share a neighbour.
    First the incoming ``g`` is summed per Gaussian, then each touched Gaussian is mapped once.
    """
    rows, k = neighbours.shape
    dim = features.shape[1]
    summed = np.zeros(features.shape, dtype=features.dtype)
    touched = np.zeros(features.shape[0], dtype=np.bool_)
    for r in range(rows):
        for j in range(k):
            i = neighbours[r, j]
            touched[i] = True
            for d in range(dim):
                summed[i, d] += grad_out[r, d]
    return _normalize_backward(features, summed, touched, k, eps)


@_jit(parallel=True)
def _normalize_backward(
    features: Array, summed: Array, touched: Array, k: int, eps: float
) -> Array:
    """Map the summed incoming gradients through ``x / max(|x|, eps)`` and the 1/k mean."""
    dim = features.shape[1]
    grad = np.zeros(features.shape, dtype=features.dtype)
    for i in prange(features.shape[0]):
        if not touched[i]:
            continue
        s = _squared_norm(features, i)
        norm = math.sqrt(s)
        if norm <= eps:
            for d in range(dim):
                grad[i, d] = summed[i, d] / (k * eps)
            continue
        dot = 0.0
        for d in range(dim):
            dot += features[i, d] * summed[i, d]
        for d in range(dim):
            grad[i, d] = (summed[i, d] - features[i, d] * dot / s) / (k * norm)
    return grad


@_jit(parallel=True)
def pair_affinity(words: Array, owner: Array, smaller: Array, cut: Array) -> Array:
    """``[T, S, S]`` bool: pixels p, q share a mask k > ``cut[t]``, or own the same mask.

    Args:
        words: ``[S, W]`` uint64 mask membership bits of each pixel (bit k = mask k).
        owner: ``[T, S]`` int64 exclusive owner of each pixel at each sample (-1 = none).
        smaller: ``[T, W]`` uint64 bits of the masks k > ``cut[t]`` (smaller scales).
        cut: ``[T]`` the samples' cuts (owners count only where ``cut[t] >= 0``).
    """
    n_t, s = owner.shape
    n_words = words.shape[1]
    out = np.empty((n_t, s, s), dtype=np.bool_)
    for p in prange(s):
        mine = np.empty(n_words, dtype=np.uint64)
        for t in range(n_t):
            for w in range(n_words):
                mine[w] = words[p, w] & smaller[t, w]
            o = owner[t, p] if cut[t] >= 0 and owner[t, p] >= 0 else -2  # -2 matches nobody
            for q in range(s):  # branch-free body
                shared = np.uint64(0)
                for w in range(n_words):
                    shared |= mine[w] & words[q, w]
                out[t, p, q] = (shared != 0) | (owner[t, q] == o)
    return out


@_jit(parallel=True)
def pair_extremes(cos: Array, affinity: Array, shift: float, low: Array, high: Array) -> None:
    """Per pair, min and max over scales of ``cos - shift * G`` (positives moved below -1).

    Args:
        cos: ``[T, B, C]`` cosines of a block of rows.
        affinity: ``[T, B, C]`` bool ground truth of the same pairs.
        shift: subtracted from the cosines of positive pairs (the loss's ``_SHIFT``).
        low, high: ``[B, C]`` outputs, written in place.
    """
    n_t, rows, cols = cos.shape
    for i in prange(rows):
        for c in range(cols):
            low[i, c] = np.inf
            high[i, c] = -np.inf
        for t in range(n_t):
            for c in range(cols):
                v = cos[t, i, c] - shift * affinity[t, i, c]
                low[i, c] = min(low[i, c], v)
                high[i, c] = max(high[i, c], v)


@_jit(parallel=True)
def pair_coefficients(cos: Array, affinity: Array, a: Array, b: Array) -> Array:
    """``[T, B, C]``: ``-a`` on positive pairs, ``b`` on negative pairs with cosine > 0, else 0."""
    n_t, rows, cols = cos.shape
    out = np.empty(cos.shape, dtype=cos.dtype)
    for i in prange(rows):
        for t in range(n_t):
            for c in range(cols):
                if affinity[t, i, c]:
                    out[t, i, c] = -a[i, c]
                elif cos[t, i, c] > 0.0:
                    out[t, i, c] = b[i, c]
                else:
                    out[t, i, c] = 0.0
    return out
