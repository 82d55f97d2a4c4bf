"""Inputs and outputs of the affinity stage."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F
from numpy.typing import NDArray
from torch import Tensor

from dcseg.affinity.gate import gate_values, quantile_transform
from dcseg.blend import BlendWeights
from dcseg.types import AgnosticMasks


@dataclass(frozen=True)
class AffinityView:
    """One training view of the affinity stage.

    Attributes:
        name: the frame stem (for log messages).
        blend: blending weights of the frozen Gaussians in this view (any resolution; mask
            pixels map to blend pixels by nearest neighbour), or a function that reads them
            (called once per training step on the view: the weights are not kept).
        masks: the frame's class-agnostic masks; None or empty = no masks, the view is skipped.
        depth: ``[H, W]`` metres (capture depth, or rendered depth where the capture has none),
            0 = invalid; used for the per-mask 3D scales.
        K: ``[3, 3]`` camera matrix of ``depth``'s resolution.
    """

    name: str
    blend: BlendWeights | Callable[[], BlendWeights]
    masks: AgnosticMasks | None
    depth: NDArray[np.float32]
    K: NDArray[np.float64]

    def weights(self) -> BlendWeights:
        """The view's blending weights (read now when given as a function)."""
        return self.blend if isinstance(self.blend, BlendWeights) else self.blend()


@dataclass(frozen=True)
class AffinityResult:
    """Trained affinity features and scale gate.

    Attributes:
        features: ``[N, D]`` saved features: mean of the L2-normalised raw features of each
            Gaussian's K nearest neighbours (not renormalised), as SAGA saves them (§3.5).
        gate_weight: ``[D, 1]`` scale-gate weight.
        gate_bias: ``[D]`` scale-gate bias.
        scale_quantiles: ``[Q]`` quantile grid of all mask scales (3D scale -> ``[0, 1]``).
        losses: the loss of every training step.
    """

    features: Tensor
    gate_weight: Tensor
    gate_bias: Tensor
    scale_quantiles: Tensor
    losses: tuple[float, ...]

    def quantile_scale(self, scale: float) -> float:
        """A 3D scale (metres) in quantile space ``[0, 1]``, the gate's input."""
        grid = self.scale_quantiles.detach().cpu().numpy()
        return float(quantile_transform(np.float64(scale), grid))


def gated_features(result: AffinityResult, scale: float) -> Tensor:
    """``[N, D]`` clustering features ``normalize(normalize(f) * g(scale))`` (§4).

    Args:
        result: the trained features and gate.
        scale: gate input in quantile space ``[0, 1]`` (the paper clusters at 0.8); use
            :meth:`AffinityResult.quantile_scale` to convert a 3D scale.
    """
    weight, bias = result.gate_weight.detach(), result.gate_bias.detach()
    gate = gate_values(weight, bias, torch.tensor([scale], device=weight.device))[0]
    return F.normalize(F.normalize(result.features.detach(), dim=-1) * gate, dim=-1)
