"""Real spherical harmonics up to degree 3, evaluated in torch (3DGS constants and sign order)."""

from __future__ import annotations

import torch
from torch import Tensor

from dcseg.gaussians import SH_C0

_C1 = 0.4886025119029199
_C2 = (
    1.0925484305920792,
    -1.0925484305920792,
    0.31539156525252005,
    -1.0925484305920792,
    0.5462742152960396,
)
_C3 = (
    -0.5900435899266435,
    2.890611442640554,
    -0.4570457994644658,
    0.3731763325901154,
    -0.4570457994644658,
    1.445305721320277,
    -0.5900435899266435,
)


def _basis(degree: int, dirs: Tensor) -> list[Tensor]:
    """The SH basis functions ``[N]`` for unit directions ``dirs [N, 3]``, up to ``degree``."""
    x, y, z = dirs.unbind(-1)
    out = [torch.full_like(x, SH_C0)]
    if degree >= 1:
        out += [-_C1 * y, _C1 * z, -_C1 * x]
    if degree >= 2:
        xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
        out += [
            _C2[0] * xy,
            _C2[1] * yz,
            _C2[2] * (2.0 * zz - xx - yy),
            _C2[3] * xz,
            _C2[4] * (xx - yy),
        ]
    if degree >= 3:
        out += [
            _C3[0] * y * (3.0 * xx - yy),
            _C3[1] * xy * z,
            _C3[2] * y * (4.0 * zz - xx - yy),
            _C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy),
            _C3[4] * x * (4.0 * zz - xx - yy),
            _C3[5] * z * (xx - yy),
            _C3[6] * x * (xx - 3.0 * yy),
        ]
    return out


def eval_sh(sh: Tensor, dirs: Tensor, degree: int | None = None) -> Tensor:
    """View-dependent RGB of each Gaussian, clamped at 0 (``0.5 + sum_k c_k Y_k(dir)``).

    Args:
        sh: ``[N, K, 3]`` coefficients.
        dirs: ``[N, 3]`` viewing directions (camera centre to Gaussian); normalised here.
        degree: the active degree (<= the coefficients' degree); None = all coefficients.

    Returns:
        ``[N, 3]`` colours, clamped below at 0 as in 3DGS.
    """
    full = round(sh.shape[1] ** 0.5) - 1
    active = full if degree is None else min(degree, full)
    unit = dirs / dirs.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    basis = torch.stack(_basis(active, unit), dim=1)  # [N, K']
    rgb = (basis.unsqueeze(-1) * sh[:, : basis.shape[1], :]).sum(dim=1)
    return (rgb + 0.5).clamp_min(0.0)
