"""The 3D Gaussian scene representation shared by rendering, reconstruction and segmentation.

Parameter conventions follow the 3D Gaussian Splatting PLY layout: quaternions ``wxyz``
(not necessarily normalised; normalise before use), log scales, opacity logits, and
spherical-harmonic colour coefficients with ``rgb = 0.5 + SH_C0 * sh[:, 0]`` at degree 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

SH_C0 = 0.28209479177387814
"""Zeroth-order real spherical harmonic constant."""


@dataclass(frozen=True)
class Gaussians:
    """N anisotropic 3D Gaussians.

    Attributes:
        means: ``[N, 3]`` world positions (metres).
        quats: ``[N, 4]`` rotations as quaternions ``wxyz``.
        log_scales: ``[N, 3]`` natural log of the standard deviations along the local axes.
        opacity_logits: ``[N]`` opacity before the sigmoid.
        sh: ``[N, K, 3]`` SH colour coefficients, ``K = (degree + 1) ** 2``.
    """

    means: Tensor
    quats: Tensor
    log_scales: Tensor
    opacity_logits: Tensor
    sh: Tensor

    def __post_init__(self) -> None:
        n = self.means.shape[0]
        expected = {
            "means": (self.means, (n, 3)),
            "quats": (self.quats, (n, 4)),
            "log_scales": (self.log_scales, (n, 3)),
            "opacity_logits": (self.opacity_logits, (n,)),
        }
        for name, (tensor, shape) in expected.items():
            if tuple(tensor.shape) != shape:
                got = tuple(tensor.shape)
                raise ValueError(f"Gaussians.{name} must have shape {shape}, got {got}")
        if self.sh.ndim != 3 or self.sh.shape[0] != n or self.sh.shape[2] != 3:
            got = tuple(self.sh.shape)
            raise ValueError(f"Gaussians.sh must have shape ({n}, K, 3), got {got}")

    def __len__(self) -> int:
        return int(self.means.shape[0])

    @property
    def sh_degree(self) -> int:
        return int(round(self.sh.shape[1] ** 0.5)) - 1

    @property
    def device(self) -> torch.device:
        return self.means.device

    def colors_dc(self) -> Tensor:
        """``[N, 3]`` view-independent RGB in [0, 1] from the SH DC term."""
        return (0.5 + SH_C0 * self.sh[:, 0]).clamp(0.0, 1.0)

    def opacities(self) -> Tensor:
        """``[N]`` opacities in (0, 1)."""
        return torch.sigmoid(self.opacity_logits)

    def to(self, device: torch.device | str) -> Gaussians:
        return Gaussians(
            self.means.to(device),
            self.quats.to(device),
            self.log_scales.to(device),
            self.opacity_logits.to(device),
            self.sh.to(device),
        )

    def detach(self) -> Gaussians:
        return Gaussians(
            self.means.detach(),
            self.quats.detach(),
            self.log_scales.detach(),
            self.opacity_logits.detach(),
            self.sh.detach(),
        )

    def subset(self, index: Tensor) -> Gaussians:
        """The Gaussians selected by a boolean mask or an index tensor."""
        return Gaussians(
            self.means[index],
            self.quats[index],
            self.log_scales[index],
            self.opacity_logits[index],
            self.sh[index],
        )
