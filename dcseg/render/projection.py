"""EWA projection of 3D Gaussians to image-space splats: the reference backend's, and the oracle
of the ``cpu`` backend's numba port (:mod:`dcseg.render.cpu_projection`), which shares its
constants and :class:`Splats`.

Follows gsplat 1.5.3 (``fully_fused_projection`` + ``isect_tiles``, pinhole, classic mode) so
that all backends agree: covariance ``R S S^T R^T``, Jacobian of the perspective projection with
the view direction clamped to 1.3x the field of view, a 0.3 px^2 low-pass dilation, opacity-aware
per-axis radii and 16x16 tiles. The only difference is the pixel-centre convention: dcseg puts
pixel centres at integer coordinates, gsplat at ``+0.5``; the tile and culling tests below are
done in gsplat's coordinates (``means2d + 0.5``) so the tile lists are identical.

Private module; plain ``Tensor`` annotations with shape comments.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

from dcseg.gaussians import Gaussians
from dcseg.render.camera import Camera

NEAR_PLANE = 0.01
"""Gaussians with view-space z below this are culled (gsplat ``near_plane``)."""
EPS2D = 0.3
"""Low-pass dilation added to the 2D covariance diagonal, px^2 (gsplat ``eps2d``)."""
ALPHA_MIN = 1.0 / 255.0
"""Per-pixel alphas below this are skipped; opacities below it are culled."""
MAX_EXTEND = 3.33
"""Largest bounding-box half-size in standard deviations (gsplat)."""
TILE_SIZE = 16
"""Tile edge in pixels."""


@dataclass(frozen=True)
class Splats:
    """The visible Gaussians projected to one image, sorted front to back (stable in depth).

    Attributes:
        means2d: ``[M, 2]`` pixel coordinates (u, v) of the projected centres.
        conics: ``[M, 3]`` inverse 2D covariance ``(a, b, c)`` = ``[[a, b], [b, c]]``.
        opacities: ``[M]`` opacities in (0, 1).
        depths: ``[M]`` view-space z.
        index: ``[M]`` int64 index of each splat into the input Gaussians.
        tile_min: ``[M, 2]`` int64 first tile (x, y) each splat touches.
        tile_max: ``[M, 2]`` int64 one past the last tile (x, y) each splat touches.
    """

    means2d: Tensor
    conics: Tensor
    opacities: Tensor
    depths: Tensor
    index: Tensor
    tile_min: Tensor
    tile_max: Tensor

    def __len__(self) -> int:
        return int(self.means2d.shape[0])


def tile_grid(width: int, height: int) -> tuple[int, int]:
    """Number of tiles along x and y."""
    return math.ceil(width / TILE_SIZE), math.ceil(height / TILE_SIZE)


def project(gaussians: Gaussians, camera: Camera) -> Splats:
    """Project, cull and depth-sort Gaussians for one camera (differentiable, autograd).

    Culling is decided without gradients on all Gaussians; the differentiable projection then
    runs on the visible ones only, so culled Gaussians (e.g. at z = 0) cannot leak NaN gradients.
    """
    dtype, device = gaussians.means.dtype, gaussians.means.device
    cam = camera.to(device, dtype)
    with torch.no_grad():
        depths, means2d, cov2d, opac = _project_raw(gaussians, cam, None)
        radii = _radii(cov2d, opac)
        keep = _visible(depths, means2d, cov2d, radii, cam).nonzero()[:, 0]
        index = keep[torch.argsort(depths[keep], stable=True)]
    depths, means2d, cov2d, opac = _project_raw(gaussians, cam, index)
    with torch.no_grad():
        tile_min, tile_max = _tile_rects(means2d, _radii(cov2d, opac), cam)
    return Splats(means2d, _conics(cov2d), opac, depths, index, tile_min, tile_max)


def _project_raw(
    gaussians: Gaussians, cam: Camera, index: Tensor | None
) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Depths [M], means2d [M, 2], dilated cov2d (xx, xy, yy) [M, 3], opacities [M] of a subset."""
    means, quats = gaussians.means, gaussians.quats
    log_scales, logits = gaussians.log_scales, gaussians.opacity_logits
    if index is not None:
        means, quats = means[index], quats[index]
        log_scales, logits = log_scales[index], logits[index]
    viewmat = cam.viewmat()
    rot_wc = viewmat[:3, :3]
    means_c = means @ rot_wc.T + viewmat[:3, 3]
    means2d, jac = _perspective(means_c, cam)
    # cov2d = J W (R S)(R S)^T W^T J^T = A A^T with A = J W R S, elementwise (no small bmm)
    jw = (jac.reshape(-1, 3) @ rot_wc).reshape(-1, 2, 3)
    a = (jw[:, :, :, None] * scaled_rotations(quats, log_scales)[:, None, :, :]).sum(2)
    cov2d = torch.stack(
        [
            (a[:, 0] * a[:, 0]).sum(-1) + EPS2D,
            (a[:, 0] * a[:, 1]).sum(-1),
            (a[:, 1] * a[:, 1]).sum(-1) + EPS2D,
        ],
        dim=-1,
    )
    return means_c[:, 2], means2d, cov2d, torch.sigmoid(logits)


def quat_to_rotmat(quats: Tensor) -> Tensor:
    """``[N, 3, 3]`` rotation matrices of (not necessarily unit) quaternions ``wxyz [N, 4]``."""
    w, x, y, z = F.normalize(quats, dim=-1).unbind(-1)
    rows = [
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ]  # fmt: skip
    return torch.stack(rows, dim=-1).reshape(-1, 3, 3)


def scaled_rotations(quats: Tensor, log_scales: Tensor) -> Tensor:
    """``R S`` [N, 3, 3] from wxyz quaternions and log scales (covariance ``R S S^T R^T``)."""
    return quat_to_rotmat(quats) * torch.exp(log_scales)[:, None, :]


def _perspective(means_c: Tensor, cam: Camera) -> tuple[Tensor, Tensor]:
    """Projected means [N, 2] and projection Jacobians [N, 2, 3] of camera-space means."""
    fx, fy, cx, cy = cam.K[0, 0], cam.K[1, 1], cam.K[0, 2], cam.K[1, 2]
    x, y, z = means_c.unbind(-1)
    # View-direction clamp as in gsplat, with gsplat's principal point (cx + 0.5).
    tan_x, tan_y = 0.5 * cam.width / fx, 0.5 * cam.height / fy
    gx, gy = cx + 0.5, cy + 0.5
    tx = z * torch.clamp(x / z, -(gx / fx + 0.3 * tan_x), (cam.width - gx) / fx + 0.3 * tan_x)
    ty = z * torch.clamp(y / z, -(gy / fy + 0.3 * tan_y), (cam.height - gy) / fy + 0.3 * tan_y)
    zero = torch.zeros_like(z)
    jac = torch.stack(
        [fx / z, zero, -fx * tx / (z * z), zero, fy / z, -fy * ty / (z * z)], dim=-1
    ).reshape(-1, 2, 3)
    means2d = torch.stack([fx * x / z + cx, fy * y / z + cy], dim=-1)
    return means2d, jac


def _conics(cov2d: Tensor) -> Tensor:
    """Inverse 2D covariances ``(a, b, c)`` [N, 3] of covariances ``(xx, xy, yy)`` [N, 3]."""
    sxx, sxy, syy = cov2d.unbind(-1)
    det = sxx * syy - sxy * sxy
    return torch.stack([syy / det, -sxy / det, sxx / det], dim=-1)


def _radii(cov2d: Tensor, opacities: Tensor) -> Tensor:
    """Opacity-aware per-axis pixel radii [N, 2] (gsplat); 0 for opacity < 1/255."""
    extend = torch.sqrt(2.0 * torch.log(opacities.clamp_min(ALPHA_MIN) / ALPHA_MIN))
    extend = extend.clamp_max(MAX_EXTEND)
    diag = cov2d[:, 0::2].clamp_min(0.0)
    radii = torch.ceil(extend[:, None] * torch.sqrt(diag))
    return torch.where((opacities >= ALPHA_MIN)[:, None], radii, torch.zeros_like(radii))


def _visible(depths: Tensor, means2d: Tensor, cov2d: Tensor, radii: Tensor, cam: Camera) -> Tensor:
    """Mask [N] of Gaussians in front of the near plane, non-degenerate and on screen."""
    det = cov2d[:, 0] * cov2d[:, 2] - cov2d[:, 1] * cov2d[:, 1]
    finite = torch.isfinite(means2d).all(-1) & torch.isfinite(radii).all(-1) & (det > 0)
    centre = means2d + 0.5  # gsplat pixel coordinates
    size = torch.tensor([cam.width, cam.height], dtype=means2d.dtype, device=means2d.device)
    on_screen = ((centre + radii) > 0).all(-1) & ((centre - radii) < size).all(-1)
    nonzero = (radii > 0).any(-1)
    return (depths >= NEAR_PLANE) & finite & on_screen & nonzero


def _tile_rects(means2d: Tensor, radii: Tensor, cam: Camera) -> tuple[Tensor, Tensor]:
    """First and one-past-last tile (x, y) [M, 2] int64 of each splat's bounding box."""
    tiles_x, tiles_y = tile_grid(cam.width, cam.height)
    limit = torch.tensor([tiles_x, tiles_y], device=means2d.device)
    centre = (means2d + 0.5) / TILE_SIZE
    half = radii / TILE_SIZE
    lo = torch.floor(centre - half).long().clamp(min=0)
    hi = torch.ceil(centre + half).long().clamp(min=0)
    return torch.minimum(lo, limit), torch.minimum(hi, limit)
