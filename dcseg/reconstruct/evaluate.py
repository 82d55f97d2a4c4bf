"""Held-out view metrics: PSNR on colour and mean absolute error on valid depth.

Depth is scored twice: the rendered mean depth (what training fits) and the surface depth
(:func:`dcseg.render.surface_depth.surface_depth`: the first surface along each ray, not a
blend with what lies behind it), which is what a depth map of the scene should show.

Colour is scored twice too: the raw PSNR of the render, and the colour-compensated PSNR after
the 3x3-plus-bias colour map that best fits the held-out image in least squares
(:func:`dcseg.reconstruct.exposure.compensated_psnr`): held-out views have no learned
exposure, and exposure-varying benchmarks score them this way. Given which pixels the training
views observed (:mod:`dcseg.reconstruct.observed`), the PSNR over those pixels as well.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import torch

from dcseg.gaussians import Gaussians
from dcseg.reconstruct.exposure import compensated_psnr, transformed
from dcseg.reconstruct.fit import render_view
from dcseg.reconstruct.losses import psnr
from dcseg.reconstruct.views import View
from dcseg.render.surface_depth import surface_depth


@dataclass(frozen=True)
class ViewMetrics:
    """Metrics of one held-out view.

    Attributes:
        name: the frame's name.
        psnr: colour PSNR in dB (rendered colour clamped to [0, 1]).
        depth_mae: mean absolute depth error in metres over valid depth pixels (NaN if none).
        surface_depth_mae: the same for the surface depth.
        depth_pixels: number of valid depth pixels.
        compensated_psnr: colour PSNR after the best affine colour map (module docstring).
        neighbour_psnr: colour PSNR under the exposure predicted from the neighbouring trained
            frames (:func:`dcseg.reconstruct.exposure.interpolated`); NaN without exposure.
        observed_psnr: colour PSNR over the pixels the training views observed (NaN when not
            measured or none was observed).
        observed_share: the share of the view's pixels they observed (NaN when not measured).
    """

    name: str
    psnr: float
    depth_mae: float
    surface_depth_mae: float
    depth_pixels: int
    compensated_psnr: float = math.nan
    neighbour_psnr: float = math.nan
    observed_psnr: float = math.nan
    observed_share: float = math.nan


@dataclass(frozen=True)
class Metrics:
    """Per-view and total held-out metrics.

    Attributes:
        views: one entry per held-out view.
        psnr: mean PSNR over views (NaN without views).
        depth_mae: depth error averaged over all valid pixels of all views (NaN if none).
        surface_depth_mae: the same for the surface depth.
        compensated_psnr: mean colour-compensated PSNR over views (NaN without views).
        neighbour_psnr: mean PSNR under the neighbours' exposure (NaN without exposure).
        observed_psnr: mean PSNR over the pixels the training views observed (NaN when not
            measured).
        observed_share: mean share of the views' pixels they observed (NaN when not measured).
    """

    views: tuple[ViewMetrics, ...]
    psnr: float
    depth_mae: float
    surface_depth_mae: float
    compensated_psnr: float = math.nan
    neighbour_psnr: float = math.nan
    observed_psnr: float = math.nan
    observed_share: float = math.nan


def evaluate_view(
    gaussians: Gaussians,
    view: View,
    degree: int,
    backend: str | None,
    *,
    planar: bool = False,
    colour: torch.Tensor | None = None,
    observed: torch.Tensor | None = None,
) -> ViewMetrics:
    """Render ``view`` and compare with its colour and valid depth (``planar``: ray-plane;
    ``colour``: the view's predicted exposure transform, for ``neighbour_psnr``; ``observed``:
    ``[H, W]`` the pixels the training views observed, for ``observed_psnr``)."""
    with torch.no_grad():
        out = render_view(gaussians, view.camera, degree, backend, planar=planar)
    surface = surface_depth(gaussians, view.camera, planar=planar)
    valid = view.depth > 0
    mean_error = _mae(out.depth, view.depth, valid)
    surface_error = _mae(surface.to(view.depth), view.depth, valid)
    count = int(valid.sum())
    raw, compensated = psnr(out.values, view.rgb), compensated_psnr(out.values, view.rgb)
    neighbour = math.nan
    if colour is not None:
        neighbour = psnr(transformed(out.values, colour.to(out.values.device)), view.rgb)
    seen_psnr, share = math.nan, math.nan
    if observed is not None:
        mask = observed.to(out.values.device)
        share = float(mask.float().mean())
        if bool(mask.any()):
            seen_psnr = psnr(out.values[mask], view.rgb[mask])
    return ViewMetrics(
        view.name, raw, mean_error, surface_error, count, compensated, neighbour, seen_psnr, share
    )


def _mae(depth: torch.Tensor, truth: torch.Tensor, valid: torch.Tensor) -> float:
    if not bool(valid.any()):
        return math.nan
    return float((depth.to(truth)[valid] - truth[valid]).abs().mean())


def evaluate(
    gaussians: Gaussians,
    views: Sequence[View],
    backend: str | None = None,
    *,
    planar: bool = False,
    colours: torch.Tensor | None = None,
    observed: Sequence[torch.Tensor] | None = None,
) -> Metrics:
    """Metrics of ``gaussians`` on ``views`` at the Gaussians' full SH degree; ``planar``: depth
    rendered as each flat Gaussian's ray-plane depth, as the reconstruction trained it;
    ``colours``: ``[len(views), 6]`` every view's predicted exposure transform, or None;
    ``observed``: per view the ``[H, W]`` pixels the training views observed, or None."""
    degree = gaussians.sh_degree
    predicted = [None] * len(views) if colours is None else list(colours)
    masks = [None] * len(views) if observed is None else list(observed)
    per_view = tuple(
        evaluate_view(gaussians, v, degree, backend, planar=planar, colour=c, observed=m)
        for v, c, m in zip(views, predicted, masks, strict=True)
    )
    pixels = sum(v.depth_pixels for v in per_view)
    mean_psnr = _mean([v.psnr for v in per_view])
    mean = _pooled([(v.depth_mae, v.depth_pixels) for v in per_view], pixels)
    surface = _pooled([(v.surface_depth_mae, v.depth_pixels) for v in per_view], pixels)
    compensated = _mean([v.compensated_psnr for v in per_view])
    neighbour = _mean([v.neighbour_psnr for v in per_view])
    seen = _mean([v.observed_psnr for v in per_view if not math.isnan(v.observed_psnr)])
    share = _mean([v.observed_share for v in per_view])
    return Metrics(per_view, mean_psnr, mean, surface, compensated, neighbour, seen, share)


def _mean(values: Sequence[float]) -> float:
    return sum(values) / len(values) if values else math.nan


def _pooled(errors: Sequence[tuple[float, int]], pixels: int) -> float:
    """The per-view errors averaged over all valid pixels."""
    weighted = sum(error * count for error, count in errors if count)
    return weighted / pixels if pixels else math.nan
