"""Held-out view metrics: PSNR on colour and mean absolute error on valid depth."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import torch

from dcseg.gaussians import Gaussians
from dcseg.reconstruct.fit import render_view
from dcseg.reconstruct.losses import psnr
from dcseg.reconstruct.views import View


@dataclass(frozen=True)
class ViewMetrics:
    """Metrics of one held-out view.

    Attributes:
        name: the frame's name.
        psnr: colour PSNR in dB (rendered colour clamped to [0, 1]).
        depth_mae: mean absolute depth error in metres over valid depth pixels (NaN if none).
        depth_pixels: number of valid depth pixels.
    """

    name: str
    psnr: float
    depth_mae: float
    depth_pixels: int


@dataclass(frozen=True)
class Metrics:
    """Per-view and total held-out metrics.

    Attributes:
        views: one entry per held-out view.
        psnr: mean PSNR over views (NaN without views).
        depth_mae: depth error averaged over all valid pixels of all views (NaN if none).
    """

    views: tuple[ViewMetrics, ...]
    psnr: float
    depth_mae: float


def evaluate_view(
    gaussians: Gaussians, view: View, degree: int, backend: str | None, *, planar: bool = False
) -> ViewMetrics:
    """Render ``view`` and compare with its colour and valid depth (``planar``: ray-plane)."""
    with torch.no_grad():
        out = render_view(gaussians, view.camera, degree, backend, planar=planar)
        valid = view.depth > 0
        count = int(valid.sum())
        error = (out.depth[valid] - view.depth[valid]).abs().mean() if count else None
    mae = math.nan if error is None else float(error)
    return ViewMetrics(view.name, psnr(out.values, view.rgb), mae, count)


def evaluate(
    gaussians: Gaussians,
    views: Sequence[View],
    backend: str | None = None,
    *,
    planar: bool = False,
) -> Metrics:
    """Metrics of ``gaussians`` on ``views`` at the Gaussians' full SH degree; ``planar``: depth
    rendered as each flat Gaussian's ray-plane depth, as the reconstruction trained it."""
    degree = gaussians.sh_degree
    per_view = tuple(evaluate_view(gaussians, v, degree, backend, planar=planar) for v in views)
    pixels = sum(v.depth_pixels for v in per_view)
    weighted = sum(v.depth_mae * v.depth_pixels for v in per_view if v.depth_pixels)
    mean_psnr = sum(v.psnr for v in per_view) / len(per_view) if per_view else math.nan
    return Metrics(per_view, mean_psnr, weighted / pixels if pixels else math.nan)
