"""The ``cpu`` backend's projection: :func:`dcseg.render.projection.project` in numba kernels.

Same contract and results as the PyTorch projection (which stays the reference backend's and
the test oracle; unlike it, no gradients flow to the camera), but one fused pass per Gaussian
forward and backward instead of ~200 whole-array operations each way: for 120k Gaussians on two
cores, ~45 ms per training step (forward + backward) instead of ~170 ms.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from torch import Tensor
from torch.autograd.function import once_differentiable

from dcseg.gaussians import Gaussians
from dcseg.render import numba_projection as npj
from dcseg.render.camera import Camera
from dcseg.render.projection import NEAR_PLANE, Splats, tile_grid


def project_cpu(gaussians: Gaussians, camera: Camera) -> Splats:
    """Project, cull and depth-sort Gaussians for one camera (differentiable, CPU tensors)."""
    outputs = ProjectGaussians.apply(  # type: ignore[no-untyped-call]
        gaussians.means, gaussians.quats, gaussians.log_scales, gaussians.opacity_logits, camera
    )
    means2d, conics, opacities, depths, index, tile_min, tile_max = outputs
    return Splats(means2d, conics, opacities, depths, index, tile_min, tile_max)


def camera_arrays(
    camera: Camera, dtype: torch.dtype
) -> tuple[np.ndarray[Any, Any], np.ndarray[Any, Any]]:
    """``view [4, 4]`` (world-to-camera) and ``[fx, fy, cx, cy, W, H]`` as float64 arrays,
    computed in ``dtype`` first as the PyTorch projection does (no camera gradients)."""
    cam = camera.to("cpu", dtype)
    view = cam.viewmat().detach().to(torch.float64).numpy()
    k = cam.K.detach().to(torch.float64)
    intr = np.array(
        [float(k[0, 0]), float(k[1, 1]), float(k[0, 2]), float(k[1, 2]),
         float(camera.width), float(camera.height)]
    )  # fmt: skip
    return np.ascontiguousarray(view), intr


def to_numpy(t: Tensor) -> np.ndarray[Any, Any]:
    return np.ascontiguousarray(t.detach().cpu().numpy())


def _depth_order(
    depths: np.ndarray[Any, Any], visible: np.ndarray[Any, Any], dtype: np.dtype[Any]
) -> np.ndarray[Any, Any]:
    """Indices of the visible Gaussians, nearest first, ties in index order.

    Depths are compared in the input precision ``dtype`` (as the PyTorch projection compares
    them); visible depths are positive and finite, so their bit patterns sort like the values.
    """
    keep = np.flatnonzero(visible)
    keys = depths[keep].astype(dtype)
    bits = keys.view(np.uint32 if keys.itemsize == 4 else np.uint64)
    return keep[npj.radix_argsort(bits)]


class ProjectGaussians(torch.autograd.Function):
    """Differentiable projection of Gaussians to depth-sorted splats with the numba kernels."""

    @staticmethod
    def forward(
        ctx: Any, means: Tensor, quats: Tensor, log_scales: Tensor, logits: Tensor, camera: Camera
    ) -> tuple[Tensor, ...]:
        """``means2d, conics, opacities, depths`` (differentiable) and ``index, tile_min/max``."""
        dtype = means.dtype
        view, intr = camera_arrays(camera, dtype)
        arrays = [to_numpy(t) for t in (means, quats, log_scales, logits)]
        near = float(np.asarray(NEAR_PLANE, dtype=arrays[0].dtype))
        depths, means2d, conics, opac, radii, visible = npj.project_all(
            arrays[0], arrays[1], arrays[2], arrays[3], view, intr, near
        )
        index = _depth_order(depths, visible, arrays[0].dtype)
        gathered = npj.gather_splats(
            index, arrays[0][:0], means2d, conics, opac, depths, radii,
            *tile_grid(camera.width, camera.height),
        )  # fmt: skip
        ctx.camera = (view, intr)
        index_t = torch.from_numpy(index)
        ctx.save_for_backward(means, quats, log_scales, logits, index_t)
        out = [torch.from_numpy(a) for a in gathered]
        ctx.mark_non_differentiable(index_t, *out[4:])
        return (*out[:4], index_t, *out[4:])

    @staticmethod
    @once_differentiable  # type: ignore[misc]
    def backward(ctx: Any, *grads: Tensor | None) -> tuple[Tensor | None, ...]:
        """Gradients for means, quats, log scales and opacity logits."""
        means, quats, log_scales, logits, index = ctx.saved_tensors
        view, intr = ctx.camera
        m = index.shape[0]
        shapes = ((m, 2), (m, 3), (m,), (m,))
        g = [
            np.zeros(shape) if grad is None else to_numpy(grad.to(torch.float64))
            for grad, shape in zip(grads[:4], shapes, strict=True)
        ]
        arrays = [to_numpy(t) for t in (means, quats, log_scales, logits)]
        out = npj.project_backward(
            to_numpy(index), arrays[0], arrays[1], arrays[2], arrays[3], view, intr,
            g[0], g[1], g[2], g[3],
        )  # fmt: skip
        result = [torch.from_numpy(a) for a in out]
        return (*result, None)
