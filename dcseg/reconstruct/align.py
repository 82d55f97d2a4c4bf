"""Align a view's pose to fitted Gaussians (frozen): held-out views of a capture whose poses
are refined carry the same pose error as the trained ones."""

from __future__ import annotations

import torch
from torch import Tensor

from dcseg.gaussians import Gaussians
from dcseg.reconstruct.config import ReconstructConfig
from dcseg.reconstruct.fit import decayed, render_view, step_loss
from dcseg.reconstruct.poses import PoseCorrections, move_gaussians
from dcseg.reconstruct.views import View


def align_pose(gaussians: Gaussians, view: View, cfg: ReconstructConfig) -> Tensor:
    """The correction (``[6]``, :mod:`dcseg.reconstruct.poses`) that best fits ``view`` to the
    frozen ``gaussians``: ``cfg.pose_align_steps`` Adam steps on the training loss, the rate
    decaying from ``cfg.pose_lr`` to a tenth of it. Zero when either is 0."""
    poses = PoseCorrections.zeros(1, cfg.pose_lr, gaussians.means.device)
    delta = poses.deltas[0]
    if cfg.pose_lr == 0 or cfg.pose_align_steps == 0:
        return delta.detach()
    frozen = gaussians.detach()
    for step in range(cfg.pose_align_steps):
        poses.set_lr(decayed(step, cfg.pose_align_steps, cfg.pose_lr))
        out = render_view(
            move_gaussians(frozen, delta, view.camera), view.camera, cfg.sh_degree, cfg.backend,
            planar=cfg.planar_depth,
        )  # fmt: skip
        torch.autograd.backward(step_loss(out, view, cfg))
        poses.step()
    return delta.detach()
