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

from dataclasses import dataclass

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

    Memory: the view's blending weights (at most :data:`MAX_PER_PIXEL` per pixel) plus the
    work of :data:`CHUNK_PIXELS` pixels at a time.

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
        blend = blend_weights(g, camera, max_per_pixel=MAX_PER_PIXEL)
        per_gaussian = _depth_terms(g, camera, planar)
        pixels = blend.height * blend.width
        out = torch.zeros(pixels, dtype=torch.float32)
        for first in range(0, pixels, CHUNK_PIXELS):
            chunk = _Chunk.of(blend, first, min(first + CHUNK_PIXELS, pixels))
            depth = _entry_depths(per_gaussian, camera, planar, chunk)
            out[first : first + chunk.pixels] = _chunk_depth(
                chunk, depth, planar, threshold, window
            )
    return out.reshape(blend.height, blend.width)


MAX_PER_PIXEL = 64
"""Contributions kept per pixel (front-most first). The median is taken of the kept weights,
so a cap that cuts thin discs' long tails moves it forward: on the surface-priors fit of
"Surfaces" (benchmarks/README.md) 32 gave 6.1 mm held-out surface depth MAE, 64 5.2 mm."""
CHUNK_PIXELS = 1 << 14
"""Pixels whose contributions are worked on at once (bounds the float64 work arrays)."""


@dataclass(frozen=True)
class _Chunk:
    """The contributions of pixels ``first .. first + pixels - 1`` of a view."""

    first: int
    pixels: int
    width: int
    rows: Tensor  # [E] pixel of each entry, relative to ``first``
    starts: Tensor  # [pixels] first entry of each pixel
    ids: Tensor  # [E] int64 Gaussian ids
    weights: Tensor  # [E] float64 blending weights

    @classmethod
    def of(cls, blend: BlendWeights, first: int, last: int) -> _Chunk:
        start, end = int(blend.offsets[first]), int(blend.offsets[last])
        counts = blend.offsets[first + 1 : last + 1] - blend.offsets[first:last]
        rows = torch.repeat_interleave(torch.arange(last - first), counts)
        starts = blend.offsets[first:last] - start
        ids, weights = blend.ids[start:end].long(), blend.weights[start:end].double()
        return cls(first, last - first, blend.width, rows, starts, ids, weights)


def _depth_terms(g: Gaussians, camera: Camera, planar: bool) -> Tensor:
    """Per Gaussian ``[N, 3]`` plane coefficients (planar) or ``[N, 1]`` centre depth."""
    if planar:
        return depth_planes(g, camera).double()
    cam = camera.to("cpu", g.means.dtype)
    return ((g.means - cam.c2w[:3, 3]) @ cam.c2w[:3, 2:3]).double()


def _entry_depths(terms: Tensor, camera: Camera, planar: bool, chunk: _Chunk) -> Tensor:
    """``[E]`` float64 depth of every contribution of the chunk along its pixel's ray."""
    t = terms[chunk.ids]
    if not planar:
        return t[:, 0]
    k = camera.K.double()
    pixel = chunk.rows + chunk.first
    u = (pixel % chunk.width).double() - k[0, 2]
    v = (pixel // chunk.width).double() - k[1, 2]
    return 1.0 / (t[:, 0] + t[:, 1] * u + t[:, 2] * v).clamp_min(MIN_INVERSE_DEPTH)


def _chunk_depth(
    chunk: _Chunk, depth: Tensor, planar: bool, threshold: float, window: float
) -> Tensor:
    """``[pixels]`` surface depth of the chunk's pixels (0 without any weight)."""
    first = first_reaching(chunk.rows, chunk.starts, chunk.weights, threshold)
    has = first < len(depth)
    median = torch.zeros(chunk.pixels, dtype=torch.float64)
    median[has] = depth[first[has]]
    near = ((depth - median[chunk.rows]).abs() <= window) & has[chunk.rows]
    w, at = chunk.weights[near], chunk.rows[near]
    value = 1.0 / depth[near] if planar else depth[near]
    weight = torch.zeros(chunk.pixels, dtype=torch.float64).index_add_(0, at, w)
    summed = torch.zeros(chunk.pixels, dtype=torch.float64).index_add_(0, at, w * value)
    mean = summed / weight.clamp_min(1e-300)
    out = 1.0 / mean.clamp_min(1e-300) if planar else mean
    return torch.where(weight > 0, out, 0.0).float()


def first_reaching(rows: Tensor, starts: Tensor, weights: Tensor, threshold: float) -> Tensor:
    """``[pixels]`` per pixel the first entry (front to back) at which its summed weight reaches
    ``threshold`` of the pixel's total; ``len(rows)`` for pixels without weight.

    ``rows [E]`` (sorted) gives each entry's pixel, ``starts [pixels]`` each pixel's first
    entry (CSR offsets), ``weights [E]`` the blending weights.
    """
    pixels = len(starts)
    total = torch.zeros(pixels, dtype=torch.float64).index_add_(0, rows, weights)
    running = torch.cumsum(weights, 0)
    before = torch.zeros(pixels, dtype=torch.float64)
    before[starts > 0] = running[starts[starts > 0] - 1]
    reached = (running - before[rows] >= threshold * total[rows] - 1e-12) & (total[rows] > 0)
    first = torch.full((pixels,), len(rows), dtype=torch.int64)
    entry = torch.arange(len(rows))
    return first.scatter_reduce_(0, rows[reached], entry[reached], reduce="amin")
