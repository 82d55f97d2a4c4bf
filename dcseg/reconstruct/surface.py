"""Surface priors of the reconstruction: Gaussians as discs centred on the observed surfaces.

Four pieces, each an option of :class:`~dcseg.reconstruct.config.ReconstructConfig`, all on by
default (the pull from the end of densification; ``--surface-priors`` starts it at the first
step and renders planar depth):

- :func:`disc_frames` starts every Gaussian as a disc in the plane of its neighbours
  (``init_thickness``) instead of an isotropic blob;
- :func:`thickness_grad` keeps them thin: the gradient of the mean of each Gaussian's
  smallest scale (``thickness_weight``);
- :func:`centre_depth_grad` pulls each centre that projects near the observed depth of the
  step's view onto it (``centre_weight``, ``centre_band``): depth from the first surface, not
  from the alpha blend the photometric and depth losses see;
- :func:`opacity_grad` makes the discs that draw a surface opaque, from the same step as the
  pull (``opacity_weight``): a wall otherwise settles as stacks of discs ~0.45 opaque, which
  no opaque centre marks.

The terms are simple enough that their gradients are written out and added to the
parameters' gradients directly (no autograd graph over every Gaussian: ~8 ms a step on 120k).
"""

from __future__ import annotations

from typing import Any

import numba
import numpy as np
import torch
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation
from torch import Tensor

from dcseg.geometry import local_axes
from dcseg.render import Camera
from dcseg.render.cpu_projection import camera_arrays, to_numpy
from dcseg.render.numba_projection import P, camera_point

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


def thickness_grad(log_scales: Tensor) -> Tensor:
    """``[N, 3]`` gradient of the thickness term, the mean over Gaussians of the smallest of
    their three scales (metres), with respect to ``log_scales``: ``s_min / N`` on each
    Gaussian's smallest axis."""
    smallest = log_scales.detach().min(dim=1)
    grad = torch.zeros_like(log_scales, memory_format=torch.contiguous_format)
    grad.scatter_(1, smallest.indices[:, None], smallest.values.exp()[:, None] / len(log_scales))
    return grad


OPACITY_FLOOR = 0.25
"""Gaussians at most this opaque are left to the image loss by the opacity term: it makes
half-transparent surface discs opaque without reviving what the images fade out."""


def opacity_grad(opacity_logits: Tensor, floor: float = OPACITY_FLOOR) -> Tensor:
    """``[N]`` (the logits' shape) gradient of the opacity term, the mean over Gaussians more
    than ``floor`` opaque of their transparency ``1 - o`` (``o = sigmoid(logit)``), with
    respect to the logits: ``-o (1 - o) / N`` there, 0 elsewhere."""
    o = torch.sigmoid(opacity_logits.detach())
    push = torch.where(o > floor, -o * (1.0 - o), torch.zeros_like(o))
    return push / max(o.shape[0], 1)


def centre_depth_grad(
    means: Tensor,
    camera: Camera,
    depth: Tensor,
    band: float,
    *,
    behind: float | None = None,
    window: int = 1,
) -> Tensor:
    """``[N, 3]`` gradient of the centre-depth term with respect to ``means``.

    The term is the mean ``|z - target|`` over the centres near their target (their view
    depth ``z``). ``target`` is the observed depth at their pixel; with ``window`` > 1 it is the
    mean of the surface nearest ``z`` among the ``window`` x ``window`` pixels around it: of
    their valid depths, those within ``behind`` of the one nearest ``z``. A centre counts when
    it lies at most ``band`` in front of its target or at most ``behind`` behind it; farther
    ones belong to other surfaces (occluded here) and are not counted. Its gradient moves each
    counted centre along the view axis by ``sign(z - target) / count``; zero when none counts.

    The window keeps a centre on an object's silhouette, whose pixel sees the surface behind,
    on the object (the mean keeps the pull unbiased on noisy depth: the nearest single depth
    would hold a centre anywhere within the noise); a narrow ``behind`` keeps the far side of
    a small object, hidden behind its near side within ``band``, from being pulled onto it.

    Args:
        means: ``[N, 3]`` Gaussian centres (world).
        camera: the view's camera (its size is ``depth``'s).
        depth: ``[H, W]`` observed depth in metres, 0 = invalid.
        band: the distance (metres) in front of the target within which a centre counts.
        behind: the distance (metres) behind the target within which it counts, and the
            depth spread of one surface in the window; None = ``band``.
        window: odd edge (pixels) of the window searched for the target; 1 = the pixel.
    """
    if window < 1 or window % 2 == 0:
        raise ValueError(f"window must be an odd number >= 1, got {window}")
    view, intr = camera_arrays(camera, means.dtype)
    back = band if behind is None else behind
    signs, count = _centre_signs(
        to_numpy(means), view, intr, to_numpy(depth), band, back, window // 2
    )
    if count == 0:
        return torch.zeros_like(means)
    axis = torch.as_tensor(view[2, :3] / count)
    return (torch.from_numpy(signs)[:, None] * axis).to(means.device, means.dtype)


@numba.njit(cache=True, nogil=True)
def _centre_signs(
    means: Any, view: Any, intr: Any, depth: Any, band: float, behind: float, radius: int
) -> tuple[Any, int]:
    """``sign(z - target)`` per counted centre (0 elsewhere) and the number counted."""
    n, height, width = means.shape[0], depth.shape[0], depth.shape[1]
    signs = np.zeros(n)
    work = np.empty((1, 3))  # row P of the projection's scratch rows: the camera-frame centre
    seen = np.empty((2 * radius + 1) ** 2)  # the window's valid depths
    count = 0
    for i in range(n):
        z = camera_point(means, i, view, work)
        if not z > 1e-6:
            continue
        u = np.rint(intr[0] * work[P, 0] / z + intr[2])
        v = np.rint(intr[1] * work[P, 1] / z + intr[3])
        if not (0 <= u < width and 0 <= v < height):  # also NaN
            continue
        iu, iv = int(u), int(v)
        k = 0
        nearest = np.inf
        for y in range(max(iv - radius, 0), min(iv + radius + 1, height)):
            for x in range(max(iu - radius, 0), min(iu + radius + 1, width)):
                d = depth[y, x]
                if d > 0:
                    seen[k] = d
                    k += 1
                    if abs(z - d) < abs(z - nearest):
                        nearest = d
        if k == 0:
            continue
        target = nearest
        if radius > 0:  # the mean of the nearest surface's depths
            total, m = 0.0, 0
            for j in range(k):
                if abs(seen[j] - nearest) <= behind:
                    total += seen[j]
                    m += 1
            target = total / m
        off = z - target
        if -band < off < behind:
            count += 1
            signs[i] = np.sign(off)
    return signs, count
