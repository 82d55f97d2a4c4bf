"""Spherical-harmonic colour evaluation."""

from __future__ import annotations

import torch

from dcseg.gaussians import SH_C0
from dcseg.reconstruct.sh import _basis, eval_sh


def test_degree_zero_is_view_independent() -> None:
    sh = torch.randn(5, 1, 3) * 0.5
    dirs = torch.randn(5, 3)
    expected = (0.5 + SH_C0 * sh[:, 0]).clamp_min(0.0)
    assert torch.allclose(eval_sh(sh, dirs), expected)
    assert torch.allclose(eval_sh(sh, -dirs), expected)


def test_degree_one_is_linear_in_direction() -> None:
    sh = torch.zeros(1, 4, 3)
    sh[0, 2, 0] = 1.0  # the z basis function, red channel
    up = eval_sh(sh, torch.tensor([[0.0, 0.0, 2.0]]))
    down = eval_sh(sh, torch.tensor([[0.0, 0.0, -1.0]]))
    assert torch.allclose(up[0], torch.tensor([0.5 + 0.4886025119029199, 0.5, 0.5]))
    assert torch.allclose(down[0], torch.tensor([0.5 - 0.4886025119029199, 0.5, 0.5]))


def test_active_degree_ignores_higher_coefficients() -> None:
    sh = torch.randn(7, 16, 3)
    dirs = torch.randn(7, 3)
    assert torch.allclose(eval_sh(sh, dirs, degree=1), eval_sh(sh[:, :4], dirs))
    assert not torch.allclose(eval_sh(sh, dirs, degree=3), eval_sh(sh[:, :4], dirs))


def test_basis_is_orthonormal_on_the_sphere() -> None:
    g = torch.Generator().manual_seed(0)
    dirs = torch.randn(30_000, 3, generator=g, dtype=torch.float64)
    dirs = dirs / dirs.norm(dim=1, keepdim=True)
    basis = torch.stack(_basis(3, dirs), dim=1)  # [M, 16]
    gram = basis.T @ basis / len(dirs) * 4 * torch.pi
    assert torch.allclose(gram, torch.eye(16, dtype=torch.float64), atol=0.05)
