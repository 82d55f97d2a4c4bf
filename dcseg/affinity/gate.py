"""The scale gate and the quantile normalisation of 3D scales (method doc Part A §3.1-§3.2).

``quantile_transform(s, fit_quantiles(all_scales))`` reproduces scikit-learn's
``QuantileTransformer(output_distribution="uniform", n_quantiles=1000).fit(all_scales)`` (without
its ``subsample``, i.e. fitted on every scale): a grid of ``Q = min(1000, n)`` empirical
quantiles, piecewise-linear interpolation averaged over both directions (for repeated quantiles),
values outside the fitted range clipped to 0 or 1.
"""

from __future__ import annotations

import numpy as np
import torch
from numpy.typing import ArrayLike, NDArray
from torch import Tensor, nn


def fit_quantiles(scales: ArrayLike, n_quantiles: int = 1000) -> NDArray[np.float64]:
    """The ``[Q]`` quantile grid of the finite ``scales``, ``Q = min(n_quantiles, n)``.

    Raises:
        ValueError: if no scale is finite.
    """
    values = np.asarray(scales, dtype=np.float64).ravel()
    values = values[np.isfinite(values)]
    if values.size == 0:
        raise ValueError("cannot fit the scale quantiles: no finite scale")
    references = np.linspace(0.0, 1.0, min(n_quantiles, values.size))
    quantiles = np.percentile(values, references * 100.0)
    return np.maximum.accumulate(quantiles)


def quantile_transform(values: ArrayLike, quantiles: ArrayLike) -> NDArray[np.float64]:
    """Map 3D scales to ``[0, 1]`` with a fitted quantile grid (monotone, clipped)."""
    x = np.asarray(values, dtype=np.float64)
    q = np.asarray(quantiles, dtype=np.float64)
    if q.size == 1:
        return np.where(x >= q[0], 1.0, 0.0)
    ref = np.linspace(0.0, 1.0, q.size)
    out = 0.5 * (np.interp(x, q, ref) - np.interp(-x, -q[::-1], -ref[::-1]))
    out = np.where(x == q[-1], 1.0, out)
    return np.where(x == q[0], 0.0, out)


class ScaleGate(nn.Module):
    """``g(s) = sigmoid(W s + b)``: a per-channel gate in ``(0, 1)^D`` of a quantile scale.

    Initialised like ``torch.nn.Linear(1, D)`` (weight and bias uniform in ``[-1, 1]`` since the
    fan-in is 1), drawn from ``generator`` so that training is seeded.
    """

    def __init__(self, dim: int, generator: torch.Generator | None = None) -> None:
        super().__init__()
        self.weight = nn.Parameter(torch.rand(dim, 1, generator=generator) * 2.0 - 1.0)
        self.bias = nn.Parameter(torch.rand(dim, generator=generator) * 2.0 - 1.0)

    def forward(self, scale: Tensor) -> Tensor:
        """``[T]`` quantile scales -> ``[T, D]`` gates."""
        return gate_values(self.weight, self.bias, scale)


def gate_values(weight: Tensor, bias: Tensor, scale: Tensor) -> Tensor:
    """``sigmoid(scale * weight + bias)``: ``[D, 1]``, ``[D]``, ``[T]`` -> ``[T, D]``."""
    return torch.sigmoid(scale[:, None].to(weight.dtype) * weight[:, 0] + bias)
