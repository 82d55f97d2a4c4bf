"""Initial Gaussians from posed depth: back-project, voxel-downsample, size from neighbours."""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence

import numpy as np
import torch
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from dcseg.gaussians import SH_C0, Gaussians
from dcseg.reconstruct.config import ReconstructConfig
from dcseg.reconstruct.depth_filter import DepthFilter
from dcseg.reconstruct.surface import disc_frames
from dcseg.types import Capture, Frame

log = logging.getLogger(__name__)

Points = NDArray[np.float64]


def backproject(
    frame: Frame, stride: int = 1, depth_filter: DepthFilter | None = None
) -> tuple[Points, NDArray[np.float64]]:
    """World points and RGB in [0, 1] of a frame's valid depth pixels on a ``stride`` grid,
    the depth denoised by ``depth_filter`` when given.

    Returns:
        ``([M, 3] points, [M, 3] colours)``, float64.
    """
    world, (u, v) = backproject_points(frame, stride, depth_filter)
    return world, frame.rgb[v, u].astype(np.float64) / 255.0


def backproject_points(
    frame: Frame, stride: int = 1, depth_filter: DepthFilter | None = None
) -> tuple[Points, tuple[NDArray[np.int64], NDArray[np.int64]]]:
    """:func:`backproject` without the colours: ``[M, 3]`` world points and their pixels'
    ``(u, v)`` columns and rows."""
    grid = (
        frame.depth[::stride, ::stride]
        if depth_filter is None
        else depth_filter.grid(frame.depth, stride)
    )
    depth = grid.astype(np.float64)
    rows, cols = np.nonzero(depth > 0)
    z = depth[rows, cols]
    u, v = cols * stride, rows * stride
    k = frame.intrinsics
    cam = np.stack([(u - k.cx) / k.fx * z, (v - k.cy) / k.fy * z, z], axis=1)
    world = cam @ frame.c2w[:3, :3].T + frame.c2w[:3, 3]
    return world, (u, v)


def project_points(
    frame: Frame, world: Points
) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float64], NDArray[np.bool_]]:
    """The inverse of :func:`backproject_points`: ``(x, y, z, inside)``, the nearest pixel of
    ``frame`` each ``[M, 3]`` ``world`` point falls on, its depth in ``frame``'s camera, and
    whether it lies in front of the camera and inside the image (``x``, ``y`` mean nothing
    elsewhere)."""
    w2c = np.linalg.inv(frame.c2w)
    local = world @ w2c[:3, :3].T + w2c[:3, 3]
    z = local[:, 2]
    ahead = z > 1e-6
    k = frame.intrinsics
    safe = np.where(ahead, z, 1.0)
    x = np.rint(local[:, 0] / safe * k.fx + k.cx).astype(np.int64)
    y = np.rint(local[:, 1] / safe * k.fy + k.cy).astype(np.int64)
    inside = ahead & (x >= 0) & (x < frame.width) & (y >= 0) & (y < frame.height)
    return x, y, z, inside


def scene_extent(frames: Sequence[Frame], stride: int = 4) -> float:
    """A scene radius (metres) that scales learning rates, voxel size and pruning.

    ``1.1 x`` the larger of the cameras' spread around their mean (as in 3DGS) and the 95th
    percentile distance of the observed surface points from that mean, so that captures taken
    from one spot (small camera spread) still get a sensible size.
    """
    centres = np.stack([f.c2w[:3, 3] for f in frames])
    centre = centres.mean(axis=0)
    camera_radius = float(np.linalg.norm(centres - centre, axis=1).max())
    points = np.concatenate(
        [backproject_points(f, stride)[0] for f in frames[:: max(1, len(frames) // 10)]]
    )
    surface_radius = 0.0
    if len(points):
        surface_radius = float(np.percentile(np.linalg.norm(points - centre, axis=1), 95))
    return 1.1 * max(camera_radius, surface_radius, 1e-3)


_MAX_KEY = np.iinfo(np.int64).max


def voxel_keys(cells: NDArray[np.int64]) -> NDArray[np.int64] | None:
    """One int64 per row of ``[M, 3]`` integer cells, ordered as the rows are (lexicographic).

    The cells are shifted to start at 0 and combined as ``(x * ny + y) * nz + z``, so sorting
    the keys sorts the rows as ``np.unique(cells, axis=0)`` does. None when ``nx * ny * nz``
    does not fit in an int64 (then only the row-wise path works).
    """
    if len(cells) == 0:
        return np.zeros(0, np.int64)
    low = cells.min(axis=0)
    spans = [int(h) - int(lo) + 1 for h, lo in zip(cells.max(axis=0), low, strict=True)]
    if spans[0] * spans[1] * spans[2] - 1 > _MAX_KEY:
        return None
    shifted = cells - low
    keys: NDArray[np.int64] = (shifted[:, 0] * spans[1] + shifted[:, 1]) * spans[2]
    keys += shifted[:, 2]
    return keys


def voxel_groups(points: Points, voxel: float) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """``(inverse [M], counts [V])``: each point's voxel (voxels in lexicographic order of
    their integer cell) and the number of points per voxel."""
    cells = np.floor(points / voxel).astype(np.int64)
    keys = voxel_keys(cells)
    if keys is None:  # the cells span more than an int64 can index: unique rows (slower)
        _, inverse, counts = np.unique(cells, axis=0, return_inverse=True, return_counts=True)
    else:
        _, inverse, counts = np.unique(keys, return_inverse=True, return_counts=True)
    return inverse.reshape(-1), counts


def voxel_means(
    points: Points,
    colours: NDArray[np.float64],
    groups: tuple[NDArray[np.intp], NDArray[np.intp]],
) -> tuple[Points, NDArray[np.float64]]:
    """The mean point and colour of each voxel of ``groups`` (from :func:`voxel_groups`)."""
    inverse, counts = groups
    m = len(counts)
    out_p = np.stack([np.bincount(inverse, points[:, i], m) for i in range(3)], axis=1)
    out_c = np.stack([np.bincount(inverse, colours[:, i], m) for i in range(3)], axis=1)
    return out_p / counts[:, None], out_c / counts[:, None]


def voxel_downsample(
    points: Points, colours: NDArray[np.float64], voxel: float
) -> tuple[Points, NDArray[np.float64]]:
    """Average the points and colours falling into each voxel of edge ``voxel``.

    Voxels come out in lexicographic order of their integer cell ``floor(p / voxel)``.
    """
    return voxel_means(points, colours, voxel_groups(points, voxel))


def auto_voxel_size(extent: float, cfg: ReconstructConfig) -> float:
    """The configured voxel size, or ``extent * voxel_fraction`` clipped to its limits."""
    if cfg.voxel_size is not None:
        return cfg.voxel_size
    return float(np.clip(extent * cfg.voxel_fraction, cfg.voxel_min, cfg.voxel_max))


def point_cloud(
    frames: Sequence[Frame], cfg: ReconstructConfig, extent: float
) -> tuple[Points, NDArray[np.float64]]:
    """The voxel-downsampled coloured cloud of all frames, at most ``cfg.max_init_points``."""
    denoise = DepthFilter.of(cfg)
    parts = [backproject(f, cfg.init_pixel_stride, denoise) for f in frames]
    points = np.concatenate([p for p, _ in parts])
    colours = np.concatenate([c for _, c in parts])
    if len(points) == 0:
        raise ValueError("no valid depth in the training frames: cannot initialise Gaussians")
    voxel = auto_voxel_size(extent, cfg)
    groups = voxel_groups(points, voxel)
    while len(groups[1]) > cfg.max_init_points:  # too many: coarser voxels, averaged only once
        voxel *= math.sqrt(len(groups[1]) / cfg.max_init_points) * 1.05
        groups = voxel_groups(points, voxel)
    log.info("init: %d depth points -> %d voxels of %.4f m", len(points), len(groups[1]), voxel)
    return voxel_means(points, colours, groups)


def neighbour_log_scales(points: Points, k: int = 3) -> NDArray[np.float64]:
    """Log of the mean distance of each point to its ``k`` nearest neighbours (``[M]``)."""
    if len(points) < 2:
        return np.full(len(points), math.log(1e-2))
    kk = min(k, len(points) - 1)
    dists, _ = cKDTree(points).query(points, k=kk + 1)
    mean = np.asarray(dists)[:, 1:].mean(axis=1)
    out: NDArray[np.float64] = np.log(np.maximum(mean, 1e-7))
    return out


def gaussians_from_points(
    points: Points,
    colours: NDArray[np.float64],
    cfg: ReconstructConfig,
    device: torch.device | str = "cpu",
) -> Gaussians:
    """Gaussians at ``points`` with colour ``colours`` (SH DC, higher orders zero).

    Isotropic, or with ``cfg.init_thickness`` discs in their neighbours' plane; either way as
    wide as the mean distance to the 3 nearest neighbours.
    """
    n = len(points)
    log_scale = np.repeat(neighbour_log_scales(points)[:, None], 3, axis=1)
    quats = np.zeros((n, 4))
    quats[:, 0] = 1.0
    if cfg.init_thickness is not None:  # discs in the plane of the neighbours
        quats, _ = disc_frames(points)
        log_scale[:, 2] += math.log(cfg.init_thickness)
    sh = np.zeros((n, (cfg.sh_degree + 1) ** 2, 3))
    sh[:, 0] = (colours - 0.5) / SH_C0
    logit = math.log(cfg.init_opacity / (1.0 - cfg.init_opacity))

    def tensor(a: NDArray[np.float64]) -> torch.Tensor:
        return torch.as_tensor(a, dtype=torch.float32, device=device)

    return Gaussians(
        means=tensor(points),
        quats=tensor(quats),
        log_scales=tensor(log_scale),
        opacity_logits=torch.full((n,), logit, dtype=torch.float32, device=device),
        sh=tensor(sh),
    )


def init_from_frames(
    frames: Sequence[Frame],
    cfg: ReconstructConfig,
    *,
    extent: float | None = None,
    device: torch.device | str = "cpu",
) -> Gaussians:
    """Initial Gaussians from the valid depth of ``frames`` (see :func:`init_from_capture`)."""
    extent = scene_extent(frames) if extent is None else extent
    points, colours = point_cloud(frames, cfg, extent)
    return gaussians_from_points(points, colours, cfg, device)


def init_from_capture(
    capture: Capture, cfg: ReconstructConfig, *, device: torch.device | str = "cpu"
) -> Gaussians:
    """Initial Gaussians from every frame's depth.

    Back-projects every ``cfg.init_pixel_stride``-th pixel with valid depth, averages the points
    per voxel (``cfg.voxel_size`` or ``extent * cfg.voxel_fraction`` clipped to
    ``[voxel_min, voxel_max]``, enlarged until at most ``cfg.max_init_points`` remain), and
    makes Gaussians (isotropic, or discs with ``cfg.init_thickness``) as wide as the mean
    distance to the 3 nearest neighbours, opacity ``cfg.init_opacity`` and SH DC from the
    voxel's mean colour.

    Args:
        capture: the posed RGB-D frames.
        cfg: the reconstruction parameters.
        device: where the returned tensors live.
    """
    return init_from_frames(capture.frames, cfg, device=device)
