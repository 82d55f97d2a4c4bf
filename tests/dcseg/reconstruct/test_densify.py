"""Density control keeps the optimizer state consistent with the parameters."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest
import torch

from dcseg.gaussians import Gaussians
from dcseg.reconstruct.config import FAST
from dcseg.reconstruct.densify import (
    GradStats,
    densify_and_prune,
    prune,
    reset_opacity,
    view_space_grad_norm,
)
from dcseg.reconstruct.fit import from_params, make_optimizer, to_params
from dcseg.render.projection import quat_to_rotmat

EXTENT = 1.0


def setup(n: int = 6, degree: int = 1):
    g = Gaussians(
        means=torch.arange(3 * n, dtype=torch.float32).reshape(n, 3) * 0.1,
        quats=torch.tensor([[1.0, 0.0, 0.0, 0.0]]).repeat(n, 1),
        log_scales=torch.full((n, 3), math.log(0.005)),
        opacity_logits=torch.zeros(n),
        sh=torch.zeros(n, (degree + 1) ** 2, 3),
    )
    params = to_params(g)
    optimizer = make_optimizer(params, FAST, EXTENT)
    loss = torch.stack([(t * (i + 1)).sum() for i, t in enumerate(params.values())]).sum()
    torch.autograd.backward(loss)
    optimizer.step()
    optimizer.zero_grad(set_to_none=True)
    return params, optimizer


def check_consistent(params, optimizer) -> None:
    n = params["means"].shape[0]
    for group in optimizer.param_groups:
        (p,) = group["params"]
        assert p is params[group["name"]]
        assert p.is_leaf and p.requires_grad and p.shape[0] == n
        state = optimizer.state[p]
        assert state["exp_avg"].shape == p.shape
        assert state["exp_avg_sq"].shape == p.shape
    from_params(params)  # shapes agree


def test_prune_keeps_rows_and_moments() -> None:
    params, optimizer = setup()
    moments = optimizer.state[params["means"]]["exp_avg"].clone()
    remove = torch.tensor([False, True, False, False, True, False])
    new = prune(optimizer, params, remove)
    check_consistent(new, optimizer)
    assert torch.equal(new["means"], params["means"].detach()[~remove])
    assert torch.equal(optimizer.state[new["means"]]["exp_avg"], moments[~remove])
    assert len(optimizer.state) == len(optimizer.param_groups)


def test_clone_split_and_prune_bookkeeping() -> None:
    params, optimizer = setup()
    with torch.no_grad():
        params["log_scales"][3] = math.log(0.05)  # large: split (> 0.01 * extent)
        params["opacity_logits"][5] = -10.0  # transparent: pruned
    stats = GradStats.zeros(6, torch.device("cpu"))
    stats.add(torch.tensor([1.0, 0.0, 0.0, 1.0, 0.0, 0.0]), torch.ones(6, dtype=torch.bool))
    old_means = params["means"].detach().clone()
    moments = optimizer.state[params["sh_dc"]]["exp_avg"].clone()
    generator = torch.Generator().manual_seed(0)
    new = densify_and_prune(optimizer, params, stats, FAST, EXTENT, generator)
    check_consistent(new, optimizer)
    # 6 - 1 split parent - 1 pruned + 1 clone + 2 children
    assert new["means"].shape[0] == 7
    assert torch.equal(new["means"][:4], old_means[[0, 1, 2, 4]])
    assert torch.equal(new["means"][4], old_means[0])  # the clone
    children = new["log_scales"][5:].detach()
    assert torch.allclose(children, torch.full((2, 3), math.log(0.05 / 1.6)))
    state = optimizer.state[new["sh_dc"]]["exp_avg"]
    assert torch.equal(state[:4], moments[[0, 1, 2, 4]])
    assert float(state[4:].abs().max()) == 0.0
    # the optimizer still works on the new leaves
    torch.autograd.backward(torch.stack([t.sum() for t in new.values()]).sum())
    optimizer.step()


def test_growth_stops_at_max_gaussians() -> None:
    params, optimizer = setup()
    stats = GradStats.zeros(6, torch.device("cpu"))
    stats.add(torch.ones(6), torch.ones(6, dtype=torch.bool))
    cfg = replace(FAST, max_gaussians=8)
    new = densify_and_prune(optimizer, params, stats, cfg, EXTENT, torch.Generator())
    assert new["means"].shape[0] == 8
    check_consistent(new, optimizer)


def test_large_gaussians_are_pruned() -> None:
    params, optimizer = setup()
    with torch.no_grad():
        params["log_scales"][2, 1] = math.log(0.5)
    stats = GradStats.zeros(6, torch.device("cpu"))
    new = densify_and_prune(optimizer, params, stats, FAST, EXTENT, torch.Generator())
    assert new["means"].shape[0] == 5
    check_consistent(new, optimizer)


def test_reset_opacity() -> None:
    params, optimizer = setup()
    reset_opacity(optimizer, params, 0.01)
    assert float(torch.sigmoid(params["opacity_logits"].detach()).max()) == pytest.approx(0.01)
    assert float(optimizer.state[params["opacity_logits"]]["exp_avg"].abs().max()) == 0.0


def test_quat_to_rotmat_is_a_rotation() -> None:
    q = torch.randn(10, 4)
    r = quat_to_rotmat(q)
    eye = torch.eye(3).expand(10, 3, 3)
    assert torch.allclose(r @ r.transpose(1, 2), eye, atol=1e-5)
    assert torch.allclose(torch.linalg.det(r), torch.ones(10), atol=1e-5)


def test_view_space_gradient_of_a_lateral_move() -> None:
    c2w = torch.eye(4)
    k = torch.tensor([[100.0, 0.0, 50.0], [0.0, 100.0, 40.0], [0.0, 0.0, 1.0]])
    means = torch.tensor([[0.0, 0.0, 2.0], [0.0, 0.0, -1.0]])
    grad = torch.tensor([[1.0, 0.0, 5.0], [1.0, 0.0, 0.0]])
    norms, visible = view_space_grad_norm(grad, means, c2w, k, 100, 80)
    # dL/du = dL/dx * z / fx = 0.02 per pixel; NDC scales by W / 2 = 50
    assert norms[0].item() == pytest.approx(1.0)
    assert visible.tolist() == [True, False]
