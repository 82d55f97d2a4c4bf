"""Adaptive density control (3DGS): clone, split, prune, opacity reset, with optimizer upkeep.

Parameters live in a dict of leaf tensors (one Adam group per name, group ``name`` = key). Every
change of the Gaussian count rebuilds the leaves and resizes Adam's moment buffers to match:
kept rows keep their moments, new rows start from zero.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from dcseg.reconstruct.config import ReconstructConfig
from dcseg.render.projection import quat_to_rotmat

Params = dict[str, Tensor]
"""Leaf tensors by name: means, quats, log_scales, opacity_logits, sh_dc, sh_rest."""


@dataclass
class GradStats:
    """Running sums of view-space position-gradient norms per Gaussian.

    Attributes:
        total: ``[N]`` summed gradient norms over the views where the Gaussian was visible.
        count: ``[N]`` number of such views.
    """

    total: Tensor
    count: Tensor

    @classmethod
    def zeros(cls, n: int, device: torch.device) -> GradStats:
        return cls(torch.zeros(n, device=device), torch.zeros(n, device=device))

    def add(self, norms: Tensor, visible: Tensor) -> None:
        """Accumulate ``norms [N]`` for the Gaussians where ``visible [N]`` is true."""
        self.total += torch.where(visible, norms, torch.zeros_like(norms))
        self.count += visible.to(self.count.dtype)

    def mean(self) -> Tensor:
        return self.total / self.count.clamp_min(1.0)


def view_space_grad_norm(
    means_grad: Tensor,
    means: Tensor,
    c2w: Tensor,
    k: Tensor,
    width: int,
    height: int,
) -> tuple[Tensor, Tensor]:
    """Approximate norm of dL/d(projected mean) in NDC units, and which Gaussians it covers.

    The renderer does not expose screen-space means, so the gradient is recovered from the
    world-space one: moving a mean by ``dx`` along the camera's x axis moves its projection by
    ``fx * dx / z`` pixels, so ``dL/du ~ (dL/dx_cam) * z / fx``; NDC rescales pixels by
    ``W / 2`` (``H / 2`` for y). Components along the viewing axis (e.g. from the depth loss)
    are ignored, as are the small contributions through the projected covariance.

    Args:
        means_grad: ``[N, 3]`` gradient of the loss with respect to world means.
        means: ``[N, 3]`` world means.
        c2w: ``[4, 4]`` camera-to-world pose.
        k: ``[3, 3]`` intrinsics.
        width: image width.
        height: image height.

    Returns:
        ``([N] norms, [N] bool visible)``; visible = in front of the camera with a nonzero
        gradient.
    """
    rot = c2w[:3, :3].to(means.dtype)
    z = (means - c2w[:3, 3].to(means.dtype)) @ rot[:, 2]
    g_cam = means_grad @ rot
    gx = g_cam[:, 0] * z / k[0, 0] * (0.5 * width)
    gy = g_cam[:, 1] * z / k[1, 1] * (0.5 * height)
    norms = torch.sqrt(gx * gx + gy * gy)
    visible = (z > 0.01) & (means_grad.abs().sum(dim=1) > 0)
    return norms, visible


def _rebuild(
    optimizer: torch.optim.Optimizer,
    params: Params,
    keep: Tensor,
    appended: Params | None = None,
) -> Params:
    """New leaves ``cat(param[keep], appended[name])`` with Adam moments resized to match."""
    out: Params = {}
    for group in optimizer.param_groups:
        name = group["name"]
        old = params[name]
        extra = appended[name] if appended else old[:0]
        new = torch.cat([old.detach()[keep], extra.detach()]).requires_grad_(True)
        state = optimizer.state.pop(old, {})
        for key in ("exp_avg", "exp_avg_sq"):
            if key in state:
                pad = torch.zeros_like(extra)
                state[key] = torch.cat([state[key][keep], pad])
        if state:
            optimizer.state[new] = state
        group["params"] = [new]
        out[name] = new
    return out


def prune(optimizer: torch.optim.Optimizer, params: Params, remove: Tensor) -> Params:
    """Drop the Gaussians where ``remove [N]`` is true."""
    return _rebuild(optimizer, params, ~remove)


def append(optimizer: torch.optim.Optimizer, params: Params, new: Params) -> Params:
    """Add Gaussians (one tensor per parameter name, same row count) with zero moments."""
    n = params["means"].shape[0]
    keep = torch.ones(n, dtype=torch.bool, device=params["means"].device)
    return _rebuild(optimizer, params, keep, new)


def _split_samples(params: Params, mask: Tensor, generator: torch.Generator) -> Params:
    """Two children per selected Gaussian, sampled from it, with scales divided by 1.6."""
    sel = {name: t.detach()[mask] for name, t in params.items()}
    scales = torch.exp(sel["log_scales"]).repeat(2, 1)
    noise = torch.randn(scales.shape, generator=generator).to(scales.device)
    rot = quat_to_rotmat(sel["quats"]).repeat(2, 1, 1)
    offsets = (rot @ (noise * scales).unsqueeze(-1)).squeeze(-1)
    children = {name: t.repeat(2, *([1] * (t.ndim - 1))) for name, t in sel.items()}
    children["means"] = children["means"] + offsets
    children["log_scales"] = children["log_scales"] - math.log(1.6)
    return children


def densify_and_prune(
    optimizer: torch.optim.Optimizer,
    params: Params,
    stats: GradStats,
    cfg: ReconstructConfig,
    extent: float,
    generator: torch.Generator,
) -> Params:
    """One 3DGS density-control step; returns the new parameter leaves.

    Gaussians whose mean view-space gradient exceeds ``cfg.grad_threshold`` are cloned when
    small (largest scale <= ``cfg.clone_scale_fraction * extent``) and split in two otherwise.
    No Gaussians are added once ``cfg.max_gaussians`` is reached. Then Gaussians with opacity
    below ``cfg.prune_opacity`` or largest scale above ``cfg.prune_scale_fraction * extent`` go.
    """
    n = params["means"].shape[0]
    big_grad = stats.mean() >= cfg.grad_threshold
    max_scale = torch.exp(params["log_scales"].detach()).amax(dim=1)
    small = max_scale <= cfg.clone_scale_fraction * extent
    clone, split = big_grad & small, big_grad & ~small
    budget = cfg.max_gaussians - n
    if budget <= 0:
        clone = split = torch.zeros_like(clone)
    elif int(clone.sum()) + int(split.sum()) > budget:
        order = torch.argsort(stats.mean(), descending=True)[budget:]
        clone[order] = False
        split[order] = False
    if bool(clone.any() | split.any()):
        new = {name: t.detach()[clone] for name, t in params.items()}
        children = _split_samples(params, split, generator)
        new = {name: torch.cat([new[name], children[name]]) for name in new}
        params = append(optimizer, params, new)
        gone = torch.cat(
            [split, torch.zeros(len(new["means"]), dtype=torch.bool, device=split.device)]
        )
        params = prune(optimizer, params, gone)
    opacity = torch.sigmoid(params["opacity_logits"].detach())
    scale = torch.exp(params["log_scales"].detach()).amax(dim=1)
    remove = (opacity < cfg.prune_opacity) | (scale > cfg.prune_scale_fraction * extent)
    if bool(remove.any()):
        params = prune(optimizer, params, remove)
    return params


def reset_opacity(optimizer: torch.optim.Optimizer, params: Params, ceiling: float = 0.01) -> None:
    """Clamp opacities to at most ``ceiling`` in place and zero their Adam moments."""
    logits = params["opacity_logits"]
    limit = math.log(ceiling / (1.0 - ceiling))
    with torch.no_grad():
        logits.clamp_(max=limit)
    state = optimizer.state.get(logits, {})
    for key in ("exp_avg", "exp_avg_sq"):
        if key in state:
            state[key].zero_()
