"""The ``cpu`` backend: numba kernels wrapped in a ``torch.autograd.Function``.

Projection runs in :mod:`dcseg.render.cpu_projection`; the Function here maps the splats
(means2d [M, 2], conics [M, 3], opacities [M], depths [M]) with per-Gaussian values [N, C] and
the splats' Gaussian index [M] to an ``[H, W, C + 2]`` image (values, depth times alpha,
alpha). The forward saves only its inputs, the tile lists, the final transmittance ``[H, W]``
and the per-pixel count of tile-list entries up to the last contributor ``[H, W]``; the
backward recomputes alphas back to front (as 3DGS does). Peak extra memory is
O(H W + n_isect (7 + C)).

Deployment note: torch and numba each run an OpenMP pool; with the default (spinning) wait policy
the two pools, and any other load, fight over the cores and the torch part can slow down 5-20x on
a 2-core machine. Set ``OMP_WAIT_POLICY=PASSIVE`` in the worker's environment (before the
process starts). The first call compiles the kernels (~10-20 s per dtype); ``cache=True`` stores
them next to this package (or in ``NUMBA_CACHE_DIR``) for later processes.
"""

from __future__ import annotations

import warnings
from typing import Any

import numba
import numpy as np
import torch
from numba.core.errors import NumbaPerformanceWarning
from torch import Tensor
from torch.autograd.function import once_differentiable

from dcseg.render import numba_kernels as nk
from dcseg.render.projection import Splats, tile_grid


class RasterizeSplats(torch.autograd.Function):
    """Differentiable compositing of depth-sorted splats with the numba kernels."""

    @staticmethod
    def forward(
        ctx: Any,
        means2d: Tensor,
        conics: Tensor,
        opacities: Tensor,
        depths: Tensor,
        values: Tensor,
        index: Tensor,
        offsets: Tensor,
        ids: Tensor,
        size: tuple[int, int],
    ) -> Tensor:
        """Composite ``[values[index], depths, 1]`` into an ``[H, W, C + 2]`` image; ``values``
        is ``[N, C]`` per Gaussian, the splat tensors are ``[M, ...]``; ``size`` is (W, H)."""
        width, height = size
        m, k, o, d, v, ix, off, idx = (
            _numpy(t) for t in (means2d, conics, opacities, depths, values, index, offsets, ids)
        )
        with _quiet():
            tiles_x = tile_grid(width, height)[0]
            shares = nk.balanced_tiles(off, numba.get_num_threads())
            image, t_final, n_contrib = nk.forward(
                m, k, o, d, v, ix, off, idx, width, height, tiles_x, *shares
            )
        ctx.size, ctx.shares = size, shares
        ctx.save_for_backward(
            means2d, conics, opacities, depths, values, index, offsets, ids,
            torch.from_numpy(t_final), torch.from_numpy(n_contrib),
        )  # fmt: skip
        return torch.from_numpy(image)

    @staticmethod
    @once_differentiable  # type: ignore[misc]
    def backward(ctx: Any, grad_image: Tensor) -> tuple[Tensor | None, ...]:
        """Gradients for means2d, conics, opacities, depths and values (None for the rest)."""
        saved = ctx.saved_tensors
        values, index = saved[4], saved[5]
        tiles_x = tile_grid(*ctx.size)[0]
        m, k, o, d, v, ix, off, idx, t_final, n_contrib = (_numpy(t) for t in saved)
        grad = _numpy(grad_image.to(values.dtype))
        with _quiet():
            per_isect = nk.backward(
                m, k, o, d, v, ix, off, idx, t_final, n_contrib, grad, tiles_x, *ctx.shares
            )
            threads = numba.get_num_threads()
            sums = torch.from_numpy(nk.sum_by_splat(per_isect, idx, index.shape[0], threads))
        channels = values.shape[1]
        grad_values = torch.zeros_like(values).index_copy_(0, index, sums[:, 6 : 6 + channels])
        grad_depths = sums[:, 6 + channels]
        return (
            sums[:, 0:2], sums[:, 2:5], sums[:, 5], grad_depths, grad_values,
            None, None, None, None,
        )  # fmt: skip


def composite_cpu(splats: Splats, values: Tensor, width: int, height: int) -> Tensor:
    """``[H, W, C + 2]``: per-Gaussian ``values [N, C]``, expected depth times alpha and alpha
    of depth-sorted splats, alpha-composited.

    Same contract as :func:`dcseg.render.torch_renderer.composite_reference`; the splat's
    Gaussian is looked up inside the kernels (no ``[M, C + 2]`` per-splat copy, and the value
    gradients go straight to the Gaussians: the projection's ``index`` is distinct).
    """
    tiles_x, tiles_y = tile_grid(width, height)
    with _quiet():
        offsets, ids = nk.bin_tiles(
            _numpy(splats.tile_min), _numpy(splats.tile_max), tiles_x * tiles_y, tiles_x
        )
    out: Tensor = RasterizeSplats.apply(  # type: ignore[no-untyped-call]
        splats.means2d, splats.conics, splats.opacities, splats.depths,
        values.to(splats.depths.dtype), splats.index,
        torch.from_numpy(offsets), torch.from_numpy(ids), (width, height),
    )  # fmt: skip
    return out


def _numpy(t: Tensor) -> np.ndarray[Any, Any]:
    return np.ascontiguousarray(t.detach().cpu().numpy())


class _quiet(warnings.catch_warnings):
    """Silence numba's performance hints (they are advice, not errors) around kernel calls."""

    def __enter__(self) -> None:
        super().__enter__()
        warnings.simplefilter("ignore", NumbaPerformanceWarning)
