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
    columns = np.ascontiguousarray(words.T)  # [W, S]: one word of every pixel in a row
    out = np.empty((n_t, s, s), dtype=np.bool_)
    for p in prange(s):
        for t in range(n_t):  # per output row: vectorisable passes over q, empty words skipped
            row, others = out[t, p], owner[t]
            o = owner[t, p] if cut[t] >= 0 and owner[t, p] >= 0 else -2  # -2 matches nobody
            for q in range(s):
                row[q] = others[q] == o
            for w in range(words.shape[1]):
                mine = words[p, w] & smaller[t, w]
                if mine == 0:
                    continue
                column = columns[w]
                for q in range(s):
                    row[q] |= (mine & column[q]) != 0
    return out


@_jit(parallel=True)
def pair_extremes(cos: Array, affinity: Array, shift: float, low: Array, high: Array) -> None:
    """Per pair, min and max over scales of ``cos - shift * G`` (positives moved below -1).

    Each row's extremes are kept in local arrays (no aliasing with the inputs) and updated with
    selects, so the column loop vectorises: 12x faster than updating ``low``/``high`` in place.

    Args:
        cos: ``[T, B, C]`` cosines of a block of rows.
        affinity: ``[T, B, C]`` bool ground truth of the same pairs.
        shift: subtracted from the cosines of positive pairs (the loss's ``_SHIFT``).
        low, high: ``[B, C]`` outputs, written in place.
    """
    n_t, rows, cols = cos.shape
    for i in prange(rows):
        lo = np.full(cols, np.inf, dtype=cos.dtype)
        hi = np.full(cols, -np.inf, dtype=cos.dtype)
        for t in range(n_t):
            row, positive = cos[t, i], affinity[t, i]
            for c in range(cols):
                v = row[c] - shift if positive[c] else row[c]
                lo[c] = v if v < lo[c] else lo[c]
                hi[c] = v if v > hi[c] else hi[c]
        low[i, :] = lo
        high[i, :] = hi


@_jit(parallel=True)
def pair_coefficients(cos: Array, affinity: Array, a: Array, b: Array) -> Array:
    """``[T, B, C]``: ``-a`` on positive pairs, ``b`` on negative pairs with cosine > 0, else 0."""
    n_t, rows, cols = cos.shape
    out = np.empty(cos.shape, dtype=cos.dtype)
    for i in prange(rows):
        for t in range(n_t):
            for c in range(cols):  # branch-free: the cosine's sign is unpredictable
                g = affinity[t, i, c]
                out[t, i, c] = b[i, c] * ((cos[t, i, c] > 0.0) and not g) - a[i, c] * g
    return out


@_jit(parallel=True)
def pair_set_counts(low: Array, high: Array, split: float) -> Array:
    """``[3]`` counts over the upper triangle: all-positive, all-negative, mixed pairs.

    Args:
        low, high: ``[S, S]`` min and max over scales of the shifted cosines
            (:func:`pair_extremes`); a pair is positive at every scale when ``high < split``,
            negative at every scale when ``low > split``.
        split: the value between shifted positives and negatives.
    """
    s = low.shape[0]
    per_row = np.zeros((s, 3), dtype=np.int64)
    for r in prange(s):
        positive = negative = mixed = 0
        for c in range(r + 1, s):
            p, n = high[r, c] < split, low[r, c] > split
            positive += p
            negative += n
            mixed += not (p or n)
        per_row[r, 0], per_row[r, 1], per_row[r, 2] = positive, negative, mixed
    return per_row.sum(axis=0)


@_jit(parallel=True)
def pair_set_weights(
    low: Array, high: Array, draw: Array, weights: Array, thresholds: Array
) -> tuple[Array, Array, Array]:
    """Pair weights on the positive and negative pair sets (0 elsewhere) and the set sizes.

    Args:
        low, high: ``[S, S]`` extremes of the shifted cosines (upper triangle used).
        draw: ``[S, S]`` uniform draws; a consistent pair is kept where ``draw`` is below its
            set's keep ratio.
        weights: ``[S, S]`` pair weights.
        thresholds: ``[6]`` in the extremes' dtype: split, keep ratio of the consistent
            positives, of the consistent negatives, the shift, the hard-positive bound (a pair
            with ``low + shift`` below it) and the hard-negative bound (``high`` above it).

    Returns:
        ``(a [S, S], b [S, S], counts [2])``: ``weights`` on the positive / negative set, and
        the sizes of both sets.
    """
    s = low.shape[0]
    split, keep_pos, keep_neg = thresholds[0], thresholds[1], thresholds[2]
    shift, hard_pos, hard_neg = thresholds[3], thresholds[4], thresholds[5]
    a = np.zeros((s, s), dtype=weights.dtype)
    b = np.zeros((s, s), dtype=weights.dtype)
    per_row = np.zeros((s, 2), dtype=np.int64)
    for r in prange(s):
        n_pos = n_neg = 0
        for c in range(r + 1, s):
            lo, hi = low[r, c], high[r, c]
            all_pos, all_neg = hi < split, lo > split
            mixed = not (all_pos or all_neg)
            if (all_pos and draw[r, c] < keep_pos) or lo + shift < hard_pos or mixed:
                a[r, c] = weights[r, c]
                n_pos += 1
            if (all_neg and draw[r, c] < keep_neg) or hi > hard_neg or mixed:
                b[r, c] = weights[r, c]
                n_neg += 1
        per_row[r, 0], per_row[r, 1] = n_pos, n_neg
    return a, b, per_row.sum(axis=0)
