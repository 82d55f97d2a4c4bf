"""The scale-gated contrastive loss with SAGA's pair mining (method doc Part A §3.4).

Pure functions of tensors; ``contrastive_loss`` is gradchecked in float64 and compared with the
plain full-matrix formula (``tests/dcseg/affinity/test_loss.py``). The pair sets are chosen
without gradient: they are piecewise constant in the cosines.

Speed: the ``[T, S, S]`` work is memory-bound, so it runs over blocks of rows (cache-sized
``[T, B, S - r0]`` slabs, columns of the upper triangle only), and the loss is written as
``sum_t sum_pq k_t(p, q) C_t(p, q)`` with coefficients ``k`` fixed under ``no_grad`` (pair sets,
``G``, the ``max(C, 0)`` switch), so no differentiable ``[T, S, S]`` cosine tensor is kept;
the pair term's gradient is built in the same pass over the blocks (:class:`_PairTerm`).
On the CPU the elementwise passes (min/max over scales, pair selection and weights,
coefficients) are fused numba kernels (:mod:`dcseg.affinity.kernels`); other devices use the
PyTorch expressions (a 40-view ``dcseg run``: training phase 107 -> 75 s,
``benchmarks/results/affinity_kernels_run40_ab.txt``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor
from torch.autograd.function import once_differentiable

from dcseg.affinity import kernels

_SHIFT = 4.0
_SPLIT = -2.0
# Positive-pair cosines are shifted by -_SHIFT into [-5, -3]; negatives stay in [-1, 1]. One
# min/max over scales then answers every mining question (see _select).


def contrastive_loss(
    features: Tensor,
    gates: Tensor,
    affinity: Tensor,
    weights: Tensor,
    draw: Tensor,
    *,
    pos_threshold: float = 0.75,
    neg_threshold: float = 0.5,
    norm_weight: float = 1.0,
    block_rows: int = 64,
) -> Tensor:
    """Contrastive loss of the rendered features of S sampled pixels at T scales.

    ``phi_t(p) = normalize(F(p) * g_t)``, ``C_t = phi_t phi_t^T`` and

    ``L = -mean_{t, Pi+}[w G C] + mean_{t, Pi-}[w (1 - G) max(C, 0)]
    + norm_weight (1 - mean_p ||F(p)||)^2``

    with the pair sets of :func:`mine_pairs` (an empty set contributes 0, where SAGA would
    average over nothing and produce NaN).

    Args:
        features: ``[S, D]`` rendered features ``F(p)``.
        gates: ``[T, D]`` scale gates ``g_t``.
        affinity: ``[T, S, S]`` bool ground truth ``G_t(p, q)``.
        weights: ``[S, S]`` pair weights ``w_pq``.
        draw: ``[S, S]`` uniform ``[0, 1)`` draws for subsampling the consistent pairs.
        pos_threshold, neg_threshold: hard-mining cosine thresholds (0.75, 0.5).
        norm_weight: weight of the feature-norm regulariser (SAGA's ``rfn``).
        block_rows: rows per block of the pair computations (speed only).

    Returns:
        The scalar loss.
    """
    phi = F.normalize(features[None, :, :] * gates[:, None, :], dim=-1)  # [T, S, D]
    mining = _Mining(affinity, weights, draw, pos_threshold, neg_threshold, block_rows)
    pairs: Tensor = _PairTerm.apply(phi, mining)  # type: ignore[no-untyped-call]
    norm = features.norm(dim=-1).mean() if features.shape[0] else features.new_zeros(())
    return pairs + norm_weight * (1.0 - norm) ** 2


@dataclass(frozen=True)
class _Mining:
    """What fixes the pair term's coefficients besides the cosines (see contrastive_loss)."""

    affinity: Tensor
    weights: Tensor
    draw: Tensor
    pos_threshold: float
    neg_threshold: float
    block_rows: int


class _PairTerm(torch.autograd.Function):
    """``sum_t sum_pq k_t(p, q) C_t(p, q)`` of ``phi [T, S, D]`` with ``k`` held constant.

    Its gradient ``sum_q k(p, q) phi_q`` (rows) plus ``sum_p k(p, q) phi_p`` (columns) is built
    in the forward pass, block by block, from the same products as the value: no ``[T, B, S]``
    coefficient block is kept for the backward pass and no per-block autograd graph is built.
    """

    @staticmethod
    def forward(ctx: Any, phi: Tensor, mining: _Mining) -> Tensor:
        """The pair term's value; its gradient is saved for :meth:`backward`."""
        value, grad = _pair_value_and_grad(phi.detach(), mining)
        ctx.save_for_backward(grad)
        return value

    @staticmethod
    @once_differentiable  # type: ignore[misc]
    def backward(ctx: Any, grad_out: Tensor) -> tuple[Tensor, None]:
        """The saved gradient times the incoming one (the mining has no gradient)."""
        (grad,) = ctx.saved_tensors
        return grad * grad_out, None


@torch.no_grad()
def _pair_value_and_grad(phi: Tensor, mining: _Mining) -> tuple[Tensor, Tensor]:
    """Value and ``[T, S, D]`` gradient of the pair term over upper-triangle row blocks."""
    m = mining
    blocks = _row_blocks(phi.shape[1], m.block_rows)
    cos = [phi[:, r0:r1] @ phi[:, r0:].transpose(1, 2) for r0, r1 in blocks]
    low, high = _extremes(cos, m.affinity, blocks, phi.shape[1])
    a, b = _pair_set_weights(low, high, m, phi.shape[0])
    value, grad = phi.new_zeros(()), torch.zeros_like(phi)
    for (r0, r1), c in zip(blocks, cos, strict=True):
        coef = _coefficients(c, m.affinity[:, r0:r1, r0:], a[r0:r1, r0:], b[r0:r1, r0:])
        rows = coef @ phi[:, r0:]  # [T, B, D]: sum_q k(p, q) phi_q
        value += (phi[:, r0:r1] * rows).sum()
        grad[:, r0:r1] += rows
        grad[:, r0:] += coef.transpose(1, 2) @ phi[:, r0:r1]
    return value, grad


@torch.no_grad()
def mine_pairs(
    cos: Tensor,
    affinity: Tensor,
    draw: Tensor,
    pos_threshold: float = 0.75,
    neg_threshold: float = 0.5,
) -> tuple[Tensor, Tensor]:
    """SAGA's pair sets ``(Pi+, Pi-)`` as ``[S, S]`` bool masks over the upper triangle p < q.

    With ``Z = sum_t G_t`` over the full matrix: consistent positives (Z = T) and negatives
    (Z = 0) are each kept with probability ``n / count`` where n is half the number of
    inconsistent pairs; hard positives (``G_t = 1`` and ``C_t < pos_threshold`` for some t), hard
    negatives (``G_t = 0`` and ``C_t > neg_threshold`` for some t) and all inconsistent pairs
    join both sets.

    Args:
        cos: ``[T, S, S]`` cosines in ``[-1, 1]``.
        affinity: ``[T, S, S]`` bool ground truth.
        draw: ``[S, S]`` uniform ``[0, 1)`` draws.
    """
    shifted = torch.where(affinity, cos - _SHIFT, cos)
    low, high = shifted.amin(0), shifted.amax(0)
    return _select(low, high, affinity, draw, pos_threshold, neg_threshold)


def _row_blocks(s: int, rows: int) -> list[tuple[int, int]]:
    return [(r0, min(r0 + rows, s)) for r0 in range(0, s, max(rows, 1))]


def _extremes(
    cos: list[Tensor], affinity: Tensor, blocks: list[tuple[int, int]], s: int
) -> tuple[Tensor, Tensor]:
    """``[S, S]`` min and max over scales of ``cos - 4 G`` (upper-triangle columns; 0 below)."""
    device, dtype = (cos[0].device, cos[0].dtype) if cos else (None, torch.float32)
    low = torch.zeros(s, s, dtype=dtype, device=device)
    high = torch.zeros(s, s, dtype=dtype, device=device)
    for (r0, r1), c in zip(blocks, cos, strict=True):
        g, lo, hi = affinity[:, r0:r1, r0:], low[r0:r1, r0:], high[r0:r1, r0:]
        if c.device.type == "cpu":  # one fused pass instead of three
            kernels.pair_extremes(c.numpy(), g.numpy(), _SHIFT, lo.numpy(), hi.numpy())
        else:
            extremes_torch(c, g, lo, hi)
    return low, high


def extremes_torch(cos: Tensor, affinity: Tensor, low: Tensor, high: Tensor) -> None:
    """:func:`dcseg.affinity.kernels.pair_extremes` in PyTorch (for devices other than CPU)."""
    u = cos.add(affinity, alpha=-_SHIFT)
    low[...], high[...] = u.amin(0), u.amax(0)  # faster than aminmax


def _coefficients(cos: Tensor, affinity: Tensor, a: Tensor, b: Tensor) -> Tensor:
    """``k_t(p, q)``: ``-a`` where ``G = 1``, ``b`` where ``G = 0`` and ``C > 0``, else 0."""
    if cos.device.type == "cpu":
        return torch.from_numpy(
            kernels.pair_coefficients(cos.numpy(), affinity.numpy(), a.numpy(), b.numpy())
        )
    return coefficients_torch(cos, affinity, a, b)


def coefficients_torch(cos: Tensor, affinity: Tensor, a: Tensor, b: Tensor) -> Tensor:
    """:func:`dcseg.affinity.kernels.pair_coefficients` in PyTorch (devices other than CPU)."""
    return torch.where(affinity, -a, (cos > 0) * b)


def _select(
    low: Tensor,
    high: Tensor,
    affinity: Tensor,
    draw: Tensor,
    pos_threshold: float,
    neg_threshold: float,
) -> tuple[Tensor, Tensor]:
    """Pair sets from the per-pair min/max of the shifted cosines (upper triangle valid)."""
    s = low.shape[0]
    upper = torch.ones(s, s, dtype=torch.bool, device=low.device).triu(diagonal=1)
    cons_pos, cons_neg = high < _SPLIT, low > _SPLIT  # every G_t = 1 / every G_t = 0
    inconsistent = ~(cons_pos | cons_neg) & upper
    # counts over the full symmetric matrix, as SAGA: twice the upper triangle plus the diagonal
    diagonal = torch.diagonal(affinity, dim1=1, dim2=2)  # [T, S]
    n_pos = 2 * (cons_pos & upper).sum() + diagonal.all(0).sum()
    n_neg = 2 * (cons_neg & upper).sum() + (~diagonal).all(0).sum()
    half = inconsistent.sum()  # = (full inconsistent count) / 2
    keep_pos = cons_pos & (draw < half / n_pos.clamp(min=1))
    keep_neg = cons_neg & (draw < half / n_neg.clamp(min=1))
    hard_pos = low + _SHIFT < pos_threshold  # min over the positives, if there is one
    hard_neg = high > max(neg_threshold, _SPLIT + 1e-3)  # max over the negatives, if any
    pos = (keep_pos | hard_pos | inconsistent) & upper
    neg = (keep_neg | hard_neg | inconsistent) & upper
    return pos, neg


def _pair_set_weights(
    low: Tensor, high: Tensor, m: _Mining, n_scales: int
) -> tuple[Tensor, Tensor]:
    """Pair weights on the positive and negative sets, each over ``T x`` its size."""
    if low.device.type == "cpu":
        return _pair_set_weights_cpu(low, high, m, n_scales)
    pos, neg = _select(low, high, m.affinity, m.draw, m.pos_threshold, m.neg_threshold)
    return _pair_scales(m.weights.to(low.dtype), pos, neg, n_scales)


def _pair_set_weights_cpu(
    low: Tensor, high: Tensor, m: _Mining, n_scales: int
) -> tuple[Tensor, Tensor]:
    """:func:`_select` then :func:`_pair_scales` in two fused numba passes, value for value
    (every threshold rounded to the extremes' dtype as PyTorch compares them)."""
    lo, hi = low.numpy(), high.numpy()
    diagonal = torch.diagonal(m.affinity, dim1=1, dim2=2)  # [T, S]
    all_pos, all_neg, half = (int(n) for n in kernels.pair_set_counts(lo, hi, _SPLIT))
    n_pos = 2 * all_pos + int(diagonal.all(0).sum())  # over the full symmetric matrix
    n_neg = 2 * all_neg + int((~diagonal).all(0).sum())
    keep = [np.float32(half) / np.float32(max(n, 1)) for n in (n_pos, n_neg)]  # as torch
    bounds = [_SPLIT, *keep, _SHIFT, m.pos_threshold, max(m.neg_threshold, _SPLIT + 1e-3)]
    a, b, sizes = kernels.pair_set_weights(
        lo,
        hi,
        m.draw.to(low.dtype).numpy(),
        m.weights.to(low.dtype).numpy(),
        np.array(bounds, dtype=lo.dtype),
    )
    scale_a, scale_b = (max(n_scales * int(n), 1) for n in sizes)
    return torch.from_numpy(a) / scale_a, torch.from_numpy(b) / scale_b


def _pair_scales(weights: Tensor, pos: Tensor, neg: Tensor, n_scales: int) -> tuple[Tensor, Tensor]:
    """``w / (T |Pi+|)`` on ``Pi+`` and ``w / (T |Pi-|)`` on ``Pi-`` (0 elsewhere)."""
    a = weights * pos / max(n_scales * int(pos.sum()), 1)
    b = weights * neg / max(n_scales * int(neg.sum()), 1)
    return a, b
