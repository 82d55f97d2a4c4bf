"""Planar depth: each flat Gaussian contributes the depth of its own plane along the pixel's ray.

The rasterizer composites one depth per splat, its centre's, over the splat's whole footprint,
so a tilted disc (a floor seen at a slant, a wall at the image edge) renders a step-shaped depth
that is wrong away from the centre by its slope times the distance. The inverse depth of a plane
is exactly linear in image coordinates, ``1 / z(u, v) = q0 + a (u - cx) + b (v - cy)`` (the
plane through the centre with the Gaussian's shortest axis as normal), and linear in the three
per-Gaussian coefficients, so it composites through the unchanged rasterizer as three extra
value channels (any backend, differentiable through the coefficients and the blending weights):
``depth = alpha / (sum_i w_i q0_i + (u - cx) sum_i w_i a_i + (v - cy) sum_i w_i b_i)``. Where
one surface covers the pixel this is its exact ray-plane depth; where surfaces mix (edges), the
harmonic blend leans towards the nearer one.

Round Gaussians have no plane: the slope is scaled by flatness ``1 - s_min / s_mid`` and a
blob renders its centre depth as before. Slopes are capped at ``MAX_TILT`` (planes seen almost
edge-on).
"""

from __future__ import annotations

import torch
from torch import Tensor

from dcseg.gaussians import Gaussians
from dcseg.render.api import render
from dcseg.render.backend import select_backend
from dcseg.render.camera import Camera, RenderOutput
from dcseg.render.projection import quat_to_rotmat

MAX_TILT = 5.0
"""Largest ``tan`` of a plane's angle to the image plane (about 79 degrees); steeper is capped."""
MIN_INVERSE_DEPTH = 1e-3
"""Floor of the blended inverse depth (1/m): a plane extrapolated past its horizon is 1 km away."""


def depth_planes(gaussians: Gaussians, camera: Camera, *, backend: str | None = None) -> Tensor:
    """``[N, 3]`` per Gaussian ``(q0, a, b)``: inverse depth ``q0 + a (u - cx) + b (v - cy)``.

    Differentiable with respect to means, quats and log scales. Gaussians behind the camera get
    zero slope; the rasterizer culls them anyway. ``backend`` as :func:`~dcseg.render.render`:
    the ``cpu`` backend computes the same in numba kernels (:mod:`dcseg.render.cpu_planar`).
    """
    if select_backend(gaussians.device, backend) == "cpu":
        from dcseg.render.cpu_planar import depth_planes_cpu

        return depth_planes_cpu(gaussians, camera)
    return planes_reference(gaussians, camera)


def planes_reference(gaussians: Gaussians, camera: Camera) -> Tensor:
    """:func:`depth_planes` in PyTorch operations (any device; the numba kernels' oracle)."""
    cam = camera.to(gaussians.means.device, gaussians.means.dtype)
    rot = cam.c2w[:3, :3]
    fx, fy = cam.K[0, 0], cam.K[1, 1]
    p = cam.to_camera(gaussians.means)
    z = p[:, 2].clamp_min(1e-6)
    axes = quat_to_rotmat(gaussians.quats)
    scales, order = gaussians.log_scales.exp().sort(dim=1)
    normal = torch.gather(axes, 2, order[:, None, :1].expand(-1, 3, 1))[:, :, 0] @ rot
    flatness = (1.0 - scales[:, 0] / scales[:, 1].clamp_min(1e-12)).clamp(0.0, 1.0)
    # 1 / z(u, v) = (n . r(u, v)) / (n . p) with r = ((u - cx) / fx, (v - cy) / fy, 1), so
    # d(1/z)/du = n_x / (fx z c) with c = n . p / z; tilt = n_x / c (the sign of n cancels).
    c = (normal * p).sum(dim=1) / z
    c = torch.where(c.abs() < 1e-6, torch.full_like(c, 1e-6), c)
    tilt_u = (normal[:, 0] / c).clamp(-MAX_TILT, MAX_TILT) * flatness
    tilt_v = (normal[:, 1] / c).clamp(-MAX_TILT, MAX_TILT) * flatness
    a = tilt_u / (z * fx)
    b = tilt_v / (z * fy)
    u0 = fx * p[:, 0] / z  # relative to the principal point
    v0 = fy * p[:, 1] / z
    return torch.stack([1.0 / z - a * u0 - b * v0, a, b], dim=1)


def render_planar(
    gaussians: Gaussians,
    values: Tensor,
    camera: Camera,
    *,
    backend: str | None = None,
) -> RenderOutput:
    """:func:`~dcseg.render.api.render` (no background) with the planar depth of the module doc."""
    channels = values.shape[1]
    planes = depth_planes(gaussians, camera, backend=backend).to(values.dtype)
    out = render(gaussians, torch.cat([values, planes], dim=1), camera, backend=backend)
    k = camera.K.to(out.values.device, out.values.dtype)
    u = torch.arange(camera.width, device=k.device, dtype=k.dtype) - k[0, 2]
    v = torch.arange(camera.height, device=k.device, dtype=k.dtype) - k[1, 2]
    q0, a, b = out.values[..., channels:].unbind(-1)
    inverse = (q0 + a * u[None, :] + b * v[:, None]).clamp_min(out.alpha * MIN_INVERSE_DEPTH)
    depth = torch.where(out.alpha > 0, out.alpha / inverse.clamp_min(1e-12), torch.zeros_like(q0))
    return RenderOutput(out.values[..., :channels], out.alpha, depth)
