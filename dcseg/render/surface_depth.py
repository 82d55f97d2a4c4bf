"""Surface depth: the depth of the first surface along a pixel's ray, not a blend of all.

The rasterizer's depth is the alpha-weighted mean over every Gaussian along the ray. Where a
ray grazes an object's silhouette and then hits the wall behind it, that mean lies in empty
space between the two. The surface depth first finds the pixel's first surface: the depth of
the Gaussian, front to back, at which the accumulated blending weight reaches ``threshold``
(half) of the pixel's alpha (the median depth). It then blends, with their blending weights,
only the Gaussians within ``window`` of that depth: the discs of one surface average out their
small errors, a wall 5 cm or more behind an object's rim does not count. Read off the view's
blending weights (:func:`~dcseg.render.blend_weights.blend_weights`, front to back), so it is
not differentiable; held-out depth is scored on it too
(:func:`dcseg.reconstruct.evaluate.evaluate_view`), beside the mean depth that training fits.

With ``planar``, each Gaussian's depth is its own plane's along the pixel's ray
(:func:`~dcseg.render.planar.depth_planes`), blended as inverse depth like
:func:`~dcseg.render.render_planar`; else its centre's, blended linearly like
:func:`~dcseg.render.render`.
"""

from __future__ import annotations

import torch
from torch import Tensor

from dcseg.blend import BlendWeights
from dcseg.gaussians import Gaussians
from dcseg.render.blend_weights import blend_weights
from dcseg.render.camera import Camera
from dcseg.render.planar import MIN_INVERSE_DEPTH, depth_planes

MEDIAN = 0.5
"""Share of a pixel's alpha at which its first surface is found."""
SURFACE_WINDOW = 0.05
"""Gaussians within this depth (m) of the first surface belong to it. On the 40-view 320x240
synthetic scene with noise-free depth (surface priors, planar depth), held-out depth MAE over
windows 1 / 2 / 5 / 10 cm and all Gaussians: 6.8 / 5.8 / 5.2 / 5.2 / 7.6 mm (median share
0.5; 0.3 / 0.4 / 0.6 gave 5.8 / 5.3 / 5.4 mm at 5 cm)."""


def surface_depth(
    gaussians: Gaussians,
    camera: Camera,
    *,
    planar: bool = False,
    threshold: float = MEDIAN,
    window: float = SURFACE_WINDOW,
) -> Tensor:
    """``[H, W]`` float32 surface depth of ``camera`` (0 where nothing is rendered).

    Args:
        gaussians: the Gaussians (any device; computed on the CPU).
        camera: the view.
        planar: each Gaussian's depth on its plane (as :func:`~dcseg.render.render_planar`).
        threshold: share of the pixel's alpha, in (0, 1], that finds the first surface.
        window: depth range (m, >= 0) behind and before the first surface that is blended.
    """
    if not 0.0 < threshold <= 1.0:
        raise ValueError(f"threshold must be in (0, 1], got {threshold}")
    if not window >= 0.0:
        raise ValueError(f"window must be >= 0, got {window}")
    g = gaussians.detach().to("cpu")
    with torch.no_grad():
        blend = blend_weights(g, camera)
        rows = blend.rows()
        depth = _entry_depths(g, camera, planar, blend, rows)
        first = first_reaching(blend, rows, threshold)
        has = first < blend.nnz
        median = torch.zeros(len(first), dtype=depth.dtype)
        median[has] = depth[first[has]]
        near = ((depth - median[rows]).abs() <= window) & has[rows]
        out = _blend_near(blend, rows, near, depth, planar)
    return out.float().reshape(blend.height, blend.width)


def first_reaching(blend: BlendWeights, rows: Tensor, threshold: float) -> Tensor:
    """``[H*W]`` per pixel the first entry (front to back) at which the summed weight reaches
    ``threshold`` of the pixel's total; ``blend.nnz`` for pixels without weight."""
    weights = blend.weights.double()
    pixels = blend.height * blend.width
    total = torch.zeros(pixels, dtype=torch.float64).index_add_(0, rows, weights)
    running = torch.cumsum(weights, 0)
    starts = blend.offsets[:-1]
    before = torch.where(starts > 0, running[(starts - 1).clamp_min(0)], 0.0)
    reached = (running - before[rows] >= threshold * total[rows] - 1e-12) & (total[rows] > 0)
    first = torch.full((pixels,), blend.nnz, dtype=torch.int64)
    entry = torch.arange(blend.nnz)
    return first.scatter_reduce_(0, rows[reached], entry[reached], reduce="amin")


def _entry_depths(
    g: Gaussians, camera: Camera, planar: bool, blend: BlendWeights, rows: Tensor
) -> Tensor:
    """``[nnz]`` float64 depth of every stored contribution along its pixel's ray."""
    cam = camera.to("cpu", torch.float64)
    ids = blend.ids.long()
    if not planar:
        local = (g.means.double()[ids] - cam.c2w[:3, 3]) @ cam.c2w[:3, :3]
        return local[:, 2]
    planes = depth_planes(g, camera)[ids].double()
    u = (rows % camera.width).double() - cam.K[0, 2]
    v = (rows // camera.width).double() - cam.K[1, 2]
    inverse = planes[:, 0] + planes[:, 1] * u + planes[:, 2] * v
    return 1.0 / inverse.clamp_min(MIN_INVERSE_DEPTH)


def _blend_near(
    blend: BlendWeights, rows: Tensor, near: Tensor, depth: Tensor, planar: bool
) -> Tensor:
    """``[H*W]`` weighted blend of the ``near`` entries' depths (inverse depth if planar)."""
    pixels = blend.height * blend.width
    w = blend.weights.double()[near]
    at = rows[near]
    value = 1.0 / depth[near] if planar else depth[near]
    weight = torch.zeros(pixels, dtype=torch.float64).index_add_(0, at, w)
    summed = torch.zeros(pixels, dtype=torch.float64).index_add_(0, at, w * value)
    mean = summed / weight.clamp_min(1e-300)
    out = 1.0 / mean.clamp_min(1e-300) if planar else mean
    return torch.where(weight > 0, out, 0.0)
