"""The pure-PyTorch reference rasterizer: readable, tiled, differentiable by autograd.

It is the test oracle for the ``cpu`` and ``gsplat`` backends. Per 16x16 tile it gathers the
splats whose bounding box touches the tile (already depth-sorted), evaluates every
(pixel, splat) alpha densely, and composites front to back with a cumulative product. Each
tile is checkpointed, so the backward pass stores only the tile inputs.
"""

from __future__ import annotations

import torch
from torch import Tensor
from torch.utils.checkpoint import checkpoint

from dcseg.render.projection import ALPHA_MIN, TILE_SIZE, Splats, tile_grid

ALPHA_MAX = 0.999
"""Per-pixel alpha clamp (gsplat's value; the original 3DGS uses 0.99)."""
T_MIN = 1e-4
"""A pixel stops compositing before the splat that would take its transmittance to <= T_MIN."""


def rasterize_reference(splats: Splats, values: Tensor, width: int, height: int) -> Tensor:
    """Alpha-composite splat values into an image, tile by tile.

    Args:
        splats: projected, depth-sorted splats (``M`` of them).
        values: ``[M, C]`` per-splat values, in the order of ``splats``.
        width: image width W.
        height: image height H.

    Returns:
        ``[H, W, C]`` composited values (no background).
    """
    tiles_x, tiles_y = tile_grid(width, height)
    rows = []
    for ty in range(tiles_y):
        row = [_tile(splats, values, tx, ty) for tx in range(tiles_x)]
        rows.append(torch.cat(row, dim=1))
    return torch.cat(rows, dim=0)[:height, :width]


def composite_reference(splats: Splats, values: Tensor, width: int, height: int) -> Tensor:
    """``[H, W, C + 2]``: per-Gaussian ``values [N, C]``, expected depth times alpha and alpha.

    Composites ``[values[splats.index], depth, 1]`` per splat with :func:`rasterize_reference`,
    so depth and alpha come out of the same pass as the values.
    """
    ones = torch.ones_like(splats.depths)[:, None]
    picked = values[splats.index].to(splats.depths.dtype)
    stacked = torch.cat([picked, splats.depths[:, None], ones], dim=1)
    return rasterize_reference(splats, stacked, width, height)


def _tile(splats: Splats, values: Tensor, tx: int, ty: int) -> Tensor:
    """The ``[TILE, TILE, C]`` composite of tile (tx, ty) (pixels past the image are cropped)."""
    corner = torch.tensor([tx, ty], device=splats.tile_min.device)
    sel = ((splats.tile_min <= corner) & (splats.tile_max > corner)).all(-1).nonzero()[:, 0]
    dtype, device = values.dtype, values.device
    if sel.numel() == 0:  # zeros that stay in the autograd graph (zero gradients, no error)
        return values[:0].sum(0).expand(TILE_SIZE, TILE_SIZE, values.shape[1])
    ys, xs = torch.meshgrid(
        torch.arange(TILE_SIZE, dtype=dtype, device=device) + ty * TILE_SIZE,
        torch.arange(TILE_SIZE, dtype=dtype, device=device) + tx * TILE_SIZE,
        indexing="ij",
    )
    pixels = torch.stack([xs.reshape(-1), ys.reshape(-1)], dim=-1)
    args = (splats.means2d[sel], splats.conics[sel], splats.opacities[sel], values[sel], pixels)
    needs_grad = torch.is_grad_enabled() and any(a.requires_grad for a in args)
    out = checkpoint(composite, *args, use_reentrant=False) if needs_grad else composite(*args)
    return out.reshape(TILE_SIZE, TILE_SIZE, -1)


def composite(
    means2d: Tensor, conics: Tensor, opacities: Tensor, values: Tensor, pixels: Tensor
) -> Tensor:
    """Front-to-back compositing of K depth-sorted splats at P pixels.

    Args:
        means2d: ``[K, 2]`` splat centres.
        conics: ``[K, 3]`` inverse 2D covariances ``(a, b, c)``.
        opacities: ``[K]`` opacities.
        values: ``[K, C]`` values.
        pixels: ``[P, 2]`` pixel coordinates (u, v).

    Returns:
        ``[P, C]`` composited values.
    """
    d = means2d[None, :, :] - pixels[:, None, :]  # [P, K, 2]
    dx, dy = d[..., 0], d[..., 1]
    a, b, c = conics.unbind(-1)
    sigma = 0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy
    alpha = torch.clamp(opacities * torch.exp(-sigma), max=ALPHA_MAX)
    alpha = torch.where((sigma >= 0) & (alpha >= ALPHA_MIN), alpha, torch.zeros_like(alpha))
    with torch.no_grad():
        alive = torch.cumprod(1.0 - alpha, dim=1) > T_MIN  # stops before the saturating splat
    alpha = torch.where(alive, alpha, torch.zeros_like(alpha))
    trans = torch.cumprod(1.0 - alpha, dim=1)
    trans = torch.cat([torch.ones_like(trans[:, :1]), trans[:, :-1]], dim=1)
    return (alpha * trans) @ values
