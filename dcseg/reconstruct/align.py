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
from dcseg.render import Camera


def align_pose(gaussians: Gaussians, view: View, cfg: ReconstructConfig) -> Tensor:
    """The correction (``[6]``, :mod:`dcseg.reconstruct.poses`) that best fits ``view`` to the
    frozen ``gaussians``: ``cfg.pose_align_steps`` Adam steps on the training loss, the rate
    decaying from ``cfg.pose_align_lr`` to a tenth of it, on the Gaussians in and near the
    view only (:func:`in_view`). Zero when refinement is off or there are no steps."""
    poses = PoseCorrections.zeros(1, cfg.pose_align_lr, gaussians.means.device)
    delta = poses.deltas[0]
    if cfg.pose_lr == 0 or cfg.pose_align_steps == 0:
        return delta.detach()
    frozen = gaussians.detach()
    frozen = frozen.subset(in_view(frozen, view.camera))
    for step in range(cfg.pose_align_steps):
        poses.set_lr(decayed(step, cfg.pose_align_steps, cfg.pose_align_lr))
        out = render_view(
            move_gaussians(frozen, delta, view.camera), view.camera, cfg.sh_degree, cfg.backend,
            planar=cfg.planar_depth,
        )  # fmt: skip
        torch.autograd.backward(step_loss(out, view, cfg))
        poses.step()
    return delta.detach()


def in_view(gaussians: Gaussians, camera: Camera, margin: float = 0.25) -> Tensor:
    """``[N]`` mask of the Gaussians whose centres lie in front of ``camera`` and project within
    its image widened by ``margin`` of its size on every side: what the view can see while
    its pose moves by a degree or two (a 320 px wide view turns ~15 px per degree)."""
    cam = camera.to_camera(gaussians.means)
    u, v = camera.to_pixels(cam).unbind(1)
    du, dv = margin * camera.width, margin * camera.height
    inside = (u > -du) & (u < camera.width + du) & (v > -dv) & (v < camera.height + dv)
    return inside & (cam[:, 2] > 0.01)
