"""The optimisation loop: Adam on Gaussian parameters against RGB and depth of training views."""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import torch
from torch import Tensor

from dcseg.gaussians import SH_C0, Gaussians
from dcseg.reconstruct.config import ReconstructConfig
from dcseg.reconstruct.densify import (
    GradStats,
    Params,
    densify_and_prune,
    reset_opacity,
    view_space_grad_norm,
)
from dcseg.reconstruct.exposure import ColourCorrections, referenced
from dcseg.reconstruct.init import auto_voxel_size
from dcseg.reconstruct.losses import depth_l1, rgb_loss
from dcseg.reconstruct.poses import PoseCorrections, corrected_camera, move_gaussians
from dcseg.reconstruct.sh import eval_sh
from dcseg.reconstruct.surface import centre_depth_grad, opacity_grad, thickness_grad
from dcseg.reconstruct.views import View, random_crop
from dcseg.render import Camera, RenderOutput, render, render_planar

log = logging.getLogger(__name__)

ProgressCallback = Callable[[int, int, float], None]
"""``on_progress(iteration, total, loss)``, called after every step (iteration counts from 1)."""


@dataclass(frozen=True)
class FitResult:
    """What :func:`optimise` returns.

    Attributes:
        gaussians: the optimised Gaussians (detached).
        losses: the training loss of every step.
        corrections: per training view its fitted pose correction (``[6]``, detached;
            :mod:`dcseg.reconstruct.poses`), None when poses are not refined.
        colour: ``[V, 6]`` per training view its fitted colour transform (log gains, biases
            of R, G, B) relative to the exported Gaussians' reference exposure
            (:func:`dcseg.reconstruct.exposure.referenced`), None when exposure is not fitted.
    """

    gaussians: Gaussians
    losses: tuple[float, ...]
    corrections: tuple[Tensor, ...] | None = None
    colour: Tensor | None = None


def to_params(gaussians: Gaussians) -> Params:
    """Leaf tensors (requiring grad) for the optimiser; ``sh_rest`` only for degree > 0."""
    g = gaussians.detach()
    params = {
        "means": g.means,
        "quats": g.quats,
        "log_scales": g.log_scales,
        "opacity_logits": g.opacity_logits,
        "sh_dc": g.sh[:, :1],
    }
    if g.sh.shape[1] > 1:
        params["sh_rest"] = g.sh[:, 1:]
    return {name: t.clone().contiguous().requires_grad_(True) for name, t in params.items()}


def from_params(params: Params) -> Gaussians:
    """The Gaussians of the current leaves (differentiable)."""
    sh = params["sh_dc"]
    if "sh_rest" in params:
        sh = torch.cat([sh, params["sh_rest"]], dim=1)
    return Gaussians(
        params["means"], params["quats"], params["log_scales"], params["opacity_logits"], sh
    )


def make_optimizer(params: Params, cfg: ReconstructConfig, extent: float) -> torch.optim.Adam:
    """Adam (eps 1e-15, fused kernels) with one group per parameter and the 3DGS rates."""
    rates = {
        "means": cfg.means_lr_init * extent,
        "quats": cfg.quats_lr,
        "log_scales": cfg.scales_lr,
        "opacity_logits": cfg.opacity_lr,
        "sh_dc": cfg.sh_dc_lr,
        "sh_rest": cfg.sh_rest_lr,
    }
    groups = [{"params": [t], "lr": rates[name], "name": name} for name, t in params.items()]
    return torch.optim.Adam(groups, lr=0.0, eps=1e-15, fused=True)


def means_lr(step: int, cfg: ReconstructConfig, extent: float) -> float:
    """Log-linear decay from ``means_lr_init`` to ``means_lr_final`` (times extent)."""
    t = min(max(step / max(cfg.iterations, 1), 0.0), 1.0)
    log_lr = (1 - t) * math.log(cfg.means_lr_init) + t * math.log(cfg.means_lr_final)
    return math.exp(log_lr) * extent


def view_colours(gaussians: Gaussians, camera: Camera, degree: int) -> Tensor:
    """``[N, 3]`` colours seen from ``camera`` with SH up to ``degree`` (clamped at 0)."""
    if degree == 0 or gaussians.sh.shape[1] == 1:
        return (0.5 + SH_C0 * gaussians.sh[:, 0]).clamp_min(0.0)
    dirs = gaussians.means - camera.c2w[:3, 3].to(gaussians.means.dtype)
    return eval_sh(gaussians.sh, dirs, degree)


def render_view(
    gaussians: Gaussians,
    camera: Camera,
    degree: int,
    backend: str | None,
    *,
    planar: bool = False,
) -> RenderOutput:
    """Render colour, alpha and expected depth of ``camera`` (black background); ``planar``:
    each flat Gaussian's ray-plane depth (:func:`dcseg.render.render_planar`)."""
    colours = view_colours(gaussians, camera, degree)
    if planar:
        return render_planar(gaussians, colours, camera, backend=backend)
    return render(gaussians, colours, camera, backend=backend)


def step_loss(
    out: RenderOutput, view: View, cfg: ReconstructConfig, colour_weight: float = 1.0
) -> Tensor:
    """``(1 - l) * L1 + l * (1 - SSIM)`` on RGB times ``colour_weight`` (below 1 for a
    motion-blurred view, :mod:`dcseg.reconstruct.sharpness`) plus the weighted depth L1 on
    valid pixels."""
    loss = rgb_loss(out.values, view.rgb, cfg.ssim_lambda)
    if colour_weight != 1.0:
        loss = colour_weight * loss
    if cfg.depth_weight > 0:
        loss = loss + cfg.depth_weight * depth_l1(out.depth, view.depth)
    return loss


def decayed(step: int, total: int, start: float) -> float:
    """Log-linear decay from ``start`` to ``start / 10`` over ``total`` steps."""
    t = min(max(step / max(total, 1), 0.0), 1.0)
    return float(start * 10.0 ** (-t))


def _view_order(n_views: int, iterations: int, generator: torch.Generator) -> list[int]:
    """Random view indices, a fresh permutation per pass over the views (as 3DGS)."""
    order: list[int] = []
    while len(order) < iterations:
        order.extend(torch.randperm(n_views, generator=generator).tolist())
    return order[:iterations]


def _add_grad(param: Tensor, grad: Tensor) -> None:
    """``param.grad += grad`` (``param.grad = grad`` when it has none yet)."""
    if param.grad is None:
        param.grad = grad
    else:
        param.grad.add_(grad)


@dataclass
class _Trainer:
    """Mutable training state; one :meth:`step` per iteration."""

    params: Params
    optimizer: torch.optim.Adam
    stats: GradStats
    cfg: ReconstructConfig
    extent: float
    generator: torch.Generator
    poses: PoseCorrections | None = None
    colour: ColourCorrections | None = None
    colour_weights: tuple[float, ...] | None = None

    def step(self, it: int, view: View, index: int) -> float:
        cfg = self.cfg
        for group in self.optimizer.param_groups:
            if group["name"] == "means":
                group["lr"] = means_lr(it, cfg, self.extent)
        degree = min(cfg.sh_degree, it // cfg.sh_degree_interval)
        gaussians, camera = from_params(self.params), view.camera
        poses = self.poses if it >= cfg.pose_from else None
        if poses is not None:
            span = cfg.iterations - cfg.pose_from
            poses.set_lr(decayed(it - cfg.pose_from, span, cfg.pose_lr))
            delta = poses.deltas[index]
            gaussians = move_gaussians(gaussians, delta, camera)
            camera = corrected_camera(camera, delta)
        out = render_view(gaussians, view.camera, degree, cfg.backend, planar=cfg.planar_depth)
        colour = self.colour
        if colour is not None:
            out = replace(out, values=colour.apply(index, out.values))
        weight = 1.0 if self.colour_weights is None else self.colour_weights[index]
        loss = step_loss(out, view, cfg, weight)
        if colour is not None:
            loss = loss + colour.penalty(index)
        torch.autograd.backward(loss)
        if it < cfg.densify_until:
            self._accumulate(camera)
        self._surface_priors(view, camera, it)  # after _accumulate: densification sees the image
        self.optimizer.step()
        self.optimizer.zero_grad(set_to_none=True)
        if poses is not None:
            poses.step()
        if colour is not None:
            colour.set_lr(decayed(it, cfg.iterations, cfg.exposure_lr))
            colour.step()
        self._control(it + 1)
        return float(loss.detach())

    def _surface_priors(self, view: View, camera: Camera, it: int) -> None:
        """Add the gradients of the thickness and centre-depth terms (not in the step loss;
        the latter from ``centre_from`` on); ``camera`` is the view's camera at its refined
        pose."""
        cfg = self.cfg
        if cfg.thickness_weight > 0:
            log_scales = self.params["log_scales"]
            _add_grad(log_scales, cfg.thickness_weight * thickness_grad(log_scales))
        if cfg.opacity_weight > 0 and it >= cfg.pull_start:
            logits = self.params["opacity_logits"]
            _add_grad(logits, cfg.opacity_weight * opacity_grad(logits))
        if cfg.centre_weight > 0 and it >= cfg.pull_start:
            voxel = auto_voxel_size(self.extent, cfg)
            behind = None if cfg.centre_behind is None else cfg.centre_behind * voxel
            grad = centre_depth_grad(
                self.params["means"],
                camera,
                view.depth,
                cfg.centre_band * voxel,
                behind=behind,
                window=cfg.centre_window,
            )
            _add_grad(self.params["means"], cfg.centre_weight * grad)

    def _accumulate(self, camera: Camera) -> None:
        means = self.params["means"]
        if means.grad is None:
            return
        with torch.no_grad():
            norms, visible = view_space_grad_norm(
                means.grad, means, camera.c2w, camera.K, camera.width, camera.height
            )
            self.stats.add(norms, visible)

    def _control(self, done: int) -> None:
        cfg = self.cfg
        if cfg.densify_from <= done <= cfg.densify_until and done % cfg.densify_every == 0:
            before = self.params["means"].shape[0]
            self.params = densify_and_prune(
                self.optimizer, self.params, self.stats, cfg, self.extent, self.generator
            )
            n = self.params["means"].shape[0]
            log.debug("step %d: densify %d -> %d Gaussians", done, before, n)
            self.stats = GradStats.zeros(n, self.params["means"].device)
        reset = cfg.opacity_reset_every
        if reset and done <= cfg.densify_until and done % reset == 0:
            reset_opacity(self.optimizer, self.params)


def optimise(
    init: Gaussians,
    views: Sequence[View],
    cfg: ReconstructConfig,
    extent: float,
    *,
    fine_views: Sequence[View] | None = None,
    on_progress: ProgressCallback | None = None,
    exposure: bool = False,
    colour_weights: Sequence[float] | None = None,
) -> FitResult:
    """Optimise ``init`` against ``views`` for ``cfg.iterations`` steps.

    Args:
        init: the starting Gaussians (their SH degree fixes the coefficient count).
        views: the training views.
        cfg: the reconstruction parameters.
        extent: the scene radius that scales position learning rates and density control.
        fine_views: the same views at full resolution, used from step ``cfg.full_res_from``.
        on_progress: called as ``on_progress(iteration, total, loss)`` after every step.
        exposure: fit a colour transform per view (:mod:`dcseg.reconstruct.exposure`); the
            returned Gaussians then hold the colours of the views' mean exposure.
        colour_weights: per view the weight of its colour loss (None = all 1).

    Returns:
        The optimised Gaussians and the loss of every step.
    """
    if not views:
        raise ValueError("no training views")
    if colour_weights is not None and len(colour_weights) != len(views):
        raise ValueError("colour_weights must hold one weight per view")
    if fine_views is not None and len(fine_views) != len(views):
        raise ValueError("fine_views must hold the same views as views")
    switch = (
        cfg.iterations if cfg.full_res_from is None or fine_views is None else cfg.full_res_from
    )
    generator = torch.Generator().manual_seed(cfg.seed)
    params = to_params(init)
    poses = None
    if cfg.pose_lr > 0:
        poses = PoseCorrections.zeros(len(views), cfg.pose_lr, init.device)
    trainer = _Trainer(
        params=params,
        optimizer=make_optimizer(params, cfg, extent),
        stats=GradStats.zeros(len(init), init.device),
        cfg=cfg,
        extent=extent,
        generator=generator,
        poses=poses,
        colour=_colour(exposure, len(views), cfg, init.device),
        colour_weights=None if colour_weights is None else tuple(map(float, colour_weights)),
    )
    losses: list[float] = []
    for it, index in enumerate(_view_order(len(views), cfg.iterations, generator)):
        if it < switch or fine_views is None:
            view = views[index]
        else:
            view = random_crop(fine_views[index], cfg.full_res_crop, generator)
        losses.append(trainer.step(it, view, index))
        if on_progress is not None:
            on_progress(it + 1, cfg.iterations, losses[-1])
    corrections = None if poses is None else tuple(d.detach() for d in poses.deltas)
    gaussians, transforms = from_params(trainer.params).detach(), None
    if trainer.colour is not None:
        gaussians, transforms = referenced(gaussians, trainer.colour.params)
    return FitResult(gaussians, tuple(losses), corrections, transforms)


def _colour(
    on: bool, n_views: int, cfg: ReconstructConfig, device: torch.device
) -> ColourCorrections | None:
    if not on:
        return None
    return ColourCorrections.identity(n_views, cfg.exposure_lr, cfg.exposure_reg, device)
