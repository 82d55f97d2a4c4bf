"""Surface priors of the reconstruction: Gaussians as discs centred on the observed surfaces.

Three pieces, each optional (:class:`~dcseg.reconstruct.config.ReconstructConfig`):

- :func:`disc_frames` starts every Gaussian as a disc in the plane of its neighbours
  (``init_thickness``) instead of an isotropic blob;
- :func:`thickness_loss` keeps them thin: the mean of each Gaussian's smallest scale
  (``thickness_weight``);
- :func:`centre_depth_loss` pulls each centre that projects near the observed depth of the
  step's view onto it (``centre_weight``, ``centre_band``): depth from the first surface, not
  from the alpha blend the photometric and depth losses see.
"""

from __future__ import annotations

import numpy as np
import torch
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation
from torch import Tensor

from dcseg.geometry import local_axes
from dcseg.render import Camera

NORMAL_NEIGHBOURS = 10
"""Neighbours whose spread gives a point's plane (principal axes of their covariance)."""


def disc_frames(points: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Each point's local plane: ``(quats [M, 4] wxyz, spread [M, 3])``.

    The rotation's columns are the principal axes of the point's ``NORMAL_NEIGHBOURS`` nearest
    neighbours, largest spread first, so the third column is the surface normal; ``spread`` is
    the standard deviation along each axis. Fewer points than neighbours: identity, unit spread.
    """
    m = len(points)
    if m <= NORMAL_NEIGHBOURS:
        quats = np.zeros((m, 4))
        quats[:, 0] = 1.0
        return quats, np.ones((m, 3))
    values, vectors = local_axes(points, NORMAL_NEIGHBOURS)
    axes = vectors[:, :, ::-1].copy()  # largest spread first, the normal last
    flip = np.linalg.det(axes) < 0
    axes[flip, :, 2] *= -1.0  # a proper rotation
    xyzw = Rotation.from_matrix(axes).as_quat()
    quats = np.concatenate([xyzw[:, 3:], xyzw[:, :3]], axis=1)
    spread = np.sqrt(np.maximum(values[:, ::-1], 0.0))
    return quats, spread


def thickness_loss(log_scales: Tensor) -> Tensor:
    """Mean over Gaussians of the smallest of their three scales (metres)."""
    return log_scales.min(dim=1).values.exp().mean()


def centre_depth_loss(means: Tensor, camera: Camera, depth: Tensor, band: float) -> Tensor:
    """Mean ``|z - depth|`` of the centres that project within ``band`` of the observed depth.

    Args:
        means: ``[N, 3]`` Gaussian centres (world).
        camera: the view's camera (its size is ``depth``'s).
        depth: ``[H, W]`` observed depth in metres, 0 = invalid.
        band: only centres whose view depth is within this distance (metres) of the observed
            depth at their pixel count; farther ones belong to other surfaces (occluded here).

    Returns:
        The mean absolute depth offset of the counted centres; 0 (still differentiable) when
        none projects near its surface.
    """
    cam = camera.to_camera(means)
    z = cam[:, 2]
    with torch.no_grad():
        u, v = torch.round(camera.to_pixels(cam)).long().unbind(1)
        inside = (z > 1e-6) & (u >= 0) & (u < camera.width) & (v >= 0) & (v < camera.height)
        seen = torch.zeros_like(z)
        seen[inside] = depth[v[inside], u[inside]].to(z.dtype)
        near = inside & (seen > 0) & ((z - seen).abs() < band)
    if not bool(near.any()):
        return means.sum() * 0.0
    return (z[near] - seen[near]).abs().mean()
