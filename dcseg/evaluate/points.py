"""Predicted labels for ground-truth 3D points: nearest-Gaussian transfer or projection vote.

``vote_projection`` is the paper's protocol (method doc §7.1) with "no vote" = -1 instead of
class 0 (Part B.8). The naive-fusion baseline is the very same vote over the class-aware 2D
maps instead of rendered label images, so :data:`naive_fusion` is that function, not a copy.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from dcseg.evaluate.config import EvaluateConfig


def transfer_nearest(
    gaussian_xyz: NDArray[Any],
    gaussian_labels: NDArray[Any],
    points: NDArray[Any],
    max_distance: float,
) -> NDArray[np.int64]:
    """Each point takes the class of its nearest Gaussian (protocol (b) of Part B.10).

    Args:
        gaussian_xyz: ``[N, 3]`` Gaussian centres.
        gaussian_labels: ``[N]`` int class per Gaussian, -1 = unlabelled.
        points: ``[P, 3]`` ground-truth points, same world frame.
        max_distance: points whose nearest Gaussian is farther than this get -1.

    Returns:
        ``[P]`` int64 class, -1 = no prediction (too far, or the nearest Gaussian is
        unlabelled: unlabelled Gaussians are not skipped in favour of farther labelled ones).
    """
    xyz = np.asarray(gaussian_xyz, dtype=np.float64).reshape(-1, 3)
    labels = np.asarray(gaussian_labels, dtype=np.int64)
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if labels.shape != (len(xyz),):
        raise ValueError(f"gaussian_labels must be [{len(xyz)}], got {labels.shape}")
    if len(xyz) == 0:
        return np.full(len(pts), -1, dtype=np.int64)
    bound = np.nextafter(max_distance, np.inf)
    dist, idx = cKDTree(xyz).query(pts, k=1, distance_upper_bound=bound)
    found = dist <= max_distance
    return np.where(found, labels[np.where(found, idx, 0)], -1).astype(np.int64)


def _linear(m: NDArray[np.float64], xyz: Sequence[NDArray[np.float64]]) -> list[NDArray[Any]]:
    """``m @ xyz`` for a 3x3 ``m`` and three coordinate rows (faster than a thin matmul)."""
    return [m[i, 0] * xyz[0] + m[i, 1] * xyz[1] + m[i, 2] * xyz[2] for i in range(3)]


def _project(
    points_t: NDArray[np.float64], k: NDArray[Any], c2w: NDArray[Any], width: int, height: int
) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64], NDArray[np.float64]]:
    """Points ``[3, P]`` in front of the camera that land in the image -> (index, row, col, z)."""
    c2w = np.asarray(c2w, dtype=np.float64)
    offset = [points_t[i] - c2w[i, 3] for i in range(3)]
    cam = _linear(c2w[:3, :3].T, offset)  # world -> camera (OpenCV axes): R^T (X - t)
    idx = np.flatnonzero(cam[2] > 0)
    cam = [c[idx] for c in cam]
    u, v, w = _linear(np.asarray(k, dtype=np.float64), cam)
    col = np.floor(u / w + 0.5)
    row = np.floor(v / w + 0.5)
    inside = (col >= 0) & (col < width) & (row >= 0) & (row < height)
    return idx[inside], row[inside].astype(np.int64), col[inside].astype(np.int64), cam[2][inside]


def transfer_opaque(
    gaussian_xyz: NDArray[Any],
    opacities: NDArray[Any],
    gaussian_labels: NDArray[Any],
    points: NDArray[Any],
    cfg: EvaluateConfig,
) -> NDArray[np.int64]:
    """The 3D protocol of the evaluation: each point takes the label of the nearest Gaussian
    whose opacity is above ``cfg.min_opacity``, if within ``cfg.max_distance`` (else -1)."""
    opaque = np.asarray(opacities).reshape(-1) > cfg.min_opacity
    labels = np.asarray(gaussian_labels)
    if opaque.shape != labels.shape:
        raise ValueError(f"opacities must be {labels.shape}, got {opaque.shape}")
    xyz = np.asarray(gaussian_xyz).reshape(-1, 3)[opaque]
    return transfer_nearest(xyz, labels[opaque], points, cfg.max_distance)


def vote_projection(
    points: NDArray[Any],
    label_images: Sequence[NDArray[Any]],
    depths: Sequence[NDArray[Any]],
    K: Sequence[NDArray[Any]],
    c2w: Sequence[NDArray[Any]],
    n_classes: int,
    depth_tol: float = 0.1,
) -> NDArray[np.int64]:
    """Label points by majority vote of per-view label images (the paper's protocol, §7.1).

    Each point is projected into each view (pixel = nearest pixel centre); the view votes
    with its label at that pixel when the point is in front of the camera, inside the image,
    ``|z - depth(v, u)| < depth_tol`` (so occluded points do not vote; depth 0 = invalid) and
    the label is >= 0.

    Args:
        points: ``[P, 3]`` world points (e.g. GT mesh vertices).
        label_images: per view, ``[H, W]`` int class per pixel, -1 = none.
        depths: per view, ``[H, W]`` float metric depth (z along the optical axis), 0 = invalid.
        K: per view, ``[3, 3]`` intrinsics of the label image's resolution.
        c2w: per view, ``[4, 4]`` camera-to-world pose, OpenCV axes.
        n_classes: C; labels must be < C.
        depth_tol: depth-agreement tolerance in metres (paper: 0.1).

    Returns:
        ``[P]`` int64 class with the most votes (ties -> smallest index), -1 = no vote.
    """
    pts = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3).T)
    if not len(label_images) == len(depths) == len(K) == len(c2w):
        raise ValueError("label_images, depths, K and c2w must have one entry per view")
    vote_dtype = np.uint16 if len(label_images) < np.iinfo(np.uint16).max else np.int64
    votes = np.zeros((pts.shape[1], n_classes), dtype=vote_dtype)
    for view, (labels, depth) in enumerate(zip(label_images, depths, strict=True)):
        labels = np.asarray(labels)
        depth = np.asarray(depth, dtype=np.float64)
        if labels.shape != depth.shape or labels.ndim != 2:
            raise ValueError(f"view {view}: label image {labels.shape} vs depth {depth.shape}")
        if labels.size and labels.max() >= n_classes:
            raise ValueError(f"view {view}: label {labels.max()} >= n_classes {n_classes}")
        idx, row, col, z = _project(pts, K[view], c2w[view], labels.shape[1], labels.shape[0])
        d = depth[row, col]
        lab = labels[row, col].astype(np.int64)
        ok = (d > 0) & (np.abs(z - d) < depth_tol) & (lab >= 0)
        votes[idx[ok], lab[ok]] += 1  # a point hits at most one pixel per view: no duplicates
    if n_classes == 0:
        return np.full(pts.shape[1], -1, dtype=np.int64)
    return np.where(votes.any(axis=1), votes.argmax(axis=1), -1).astype(np.int64)


naive_fusion = vote_projection
"""The naive-fusion baseline: :func:`vote_projection` applied to the class-aware 2D maps
(``SemanticMap.classes``) as label images, with the capture's depth, intrinsics and poses."""
