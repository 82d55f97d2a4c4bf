"""Plane geometry of stuff surfaces: which clusters lie on one surface, and a region's planes.

Stuff classes (walls, floor ...) become one region per connected surface, not objects
(:mod:`dcseg.assign.instances`). Two touching clusters of a stuff class are one surface when
they are coplanar (:func:`coplanar` of their :func:`cluster_planes`); a region that one cluster
wraps round a room's corner splits into its planes (:func:`split_stuff_planes`), which the
cluster-level test cannot see. So walls meeting at a corner are two regions.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from dcseg.assign.config import AssignConfig
from dcseg.geometry import local_axes


def cluster_planes(
    means: NDArray[np.float64], cluster_labels: NDArray[np.int64], k: int
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``centroids [K, 3]`` and unit ``normals [K, 3]`` (direction of least variance) of every
    cluster's Gaussian centres; zeros for empty clusters."""
    member = cluster_labels >= 0
    lab, pts = cluster_labels[member], means[member]
    count = np.maximum(np.bincount(lab, minlength=k), 1).astype(np.float64)
    sums = np.stack([np.bincount(lab, pts[:, i], k) for i in range(3)], axis=1)
    centroids: NDArray[np.float64] = sums.astype(np.float64) / count[:, None]
    d = pts - centroids[lab]
    cov = np.zeros((k, 3, 3))
    np.add.at(cov, lab, d[:, :, None] * d[:, None, :])
    _, vectors = np.linalg.eigh(cov)
    normals: NDArray[np.float64] = vectors[:, :, 0]
    return centroids, normals


def coplanar(
    centroids: NDArray[np.float64],
    normals: NDArray[np.float64],
    a: NDArray[np.int64],
    b: NDArray[np.int64],
    cfg: AssignConfig,
) -> NDArray[np.bool_]:
    """Cluster pairs on one surface: their normals agree (|cos| >= ``surface_min_normal_cosine``)
    and the step between their centroids lies in both planes (its |cosine| with either normal
    is at most ``surface_max_tilt``)."""
    same = np.abs(np.einsum("ij,ij->i", normals[a], normals[b])) >= cfg.surface_min_normal_cosine
    step = centroids[b] - centroids[a]
    step /= np.maximum(np.linalg.norm(step, axis=1, keepdims=True), 1e-12)
    flat_a = np.abs(np.einsum("ij,ij->i", normals[a], step)) <= cfg.surface_max_tilt
    flat_b = np.abs(np.einsum("ij,ij->i", normals[b], step)) <= cfg.surface_max_tilt
    out: NDArray[np.bool_] = same & flat_a & flat_b
    return out


PLANE_NEIGHBOURS = 16
"""Neighbours whose spread gives a stuff Gaussian's local normal (:func:`split_stuff_planes`)."""

PLANE_CANDIDATES = 256
"""Normals tried as a region's dominant plane direction per round (evenly spaced picks)."""

PLANE_VOTERS = 4096
"""Normals (evenly spaced) whose agreement ranks the candidates of a round."""


def plane_labels(
    normals: NDArray[np.float64], min_cosine: float, min_points: int
) -> NDArray[np.int64]:
    """Group unit normals (up to sign) by direction: ``[M]`` group per normal, -1 = none.

    Each round takes the candidate normal that most remaining normals agree with
    (|cosine| >= ``min_cosine``; counted on :data:`PLANE_VOTERS` of them) and gives the
    agreeing normals a group, while such a group holds at least
    ``min_points`` normals; the rest stay -1.
    """
    out = np.full(len(normals), -1, dtype=np.int64)
    for label in range(len(normals)):
        free = np.flatnonzero(out < 0)
        if len(free) < min_points:
            break
        picks = free[_spaced(len(free), PLANE_CANDIDATES)]
        voters = free[_spaced(len(free), PLANE_VOTERS)]
        votes = (np.abs(normals[picks] @ normals[voters].T) >= min_cosine).sum(axis=1)
        best = normals[picks[int(votes.argmax())]]
        members = free[np.abs(normals[free] @ best) >= min_cosine]
        if len(members) < min_points:
            break
        out[members] = label
    return out


def _spaced(n: int, most: int) -> NDArray[np.intp]:
    """At most ``most`` evenly spaced indices into ``n`` items."""
    return np.linspace(0, n - 1, min(most, n)).astype(np.intp)


def split_stuff_planes(
    means: NDArray[np.float64],
    group: NDArray[np.int64],
    semantic: NDArray[np.int64],
    stuff: NDArray[np.bool_],
    radius: float,
    cfg: AssignConfig,
) -> NDArray[np.int64]:
    """Stuff regions split into their planes: one cluster that wraps round a room's corner
    holds two walls, which the cluster-level coplanar test cannot separate.

    Per stuff region, the Gaussians' local normals (:data:`PLANE_NEIGHBOURS`) are grouped by
    direction (:func:`plane_labels`, |cosine| >= ``surface_min_normal_cosine``; a direction
    needs ``plane_min_share`` of the region); Gaussians of no direction (corners, noisy normals)
    join the direction of their nearest grouped neighbour; each direction then splits into
    connected pieces (centres within ``radius``), and pieces below ``plane_min_share`` of the
    region join the piece nearest to them. A region with one direction stays whole unless it
    falls apart into large pieces.
    """
    out = group.copy()
    next_key = int(group.max(initial=-1)) + 1
    for key in np.unique(group[group >= 0]):
        rows = np.flatnonzero(group == key)
        cls = semantic[rows[0]]
        if not (0 <= cls < len(stuff) and stuff[cls]) or len(rows) <= PLANE_NEIGHBOURS:
            continue
        pieces = _plane_pieces(means[rows], radius, cfg)
        for piece in range(1, int(pieces.max(initial=0)) + 1):
            out[rows[pieces == piece]] = next_key
            next_key += 1
    return out


def _plane_pieces(
    points: NDArray[np.float64], radius: float, cfg: AssignConfig
) -> NDArray[np.int64]:
    """``[M]`` piece per point of one stuff region (0 = the first piece)."""
    _, vectors = local_axes(points, PLANE_NEIGHBOURS)
    min_points = max(int(np.ceil(cfg.plane_min_share * len(points))), 1)
    direction = plane_labels(vectors[:, :, 0], cfg.surface_min_normal_cosine, min_points)
    placed = np.flatnonzero(direction >= 0)
    if len(placed) == 0:
        return np.zeros(len(points), dtype=np.int64)
    loose = np.flatnonzero(direction < 0)
    if len(loose):
        _, nearest = cKDTree(points[placed]).query(points[loose])
        direction[loose] = direction[placed[nearest]]
    pieces = np.zeros(len(points), dtype=np.int64)
    offset = 0
    for d in range(int(direction.max()) + 1):
        rows = np.flatnonzero(direction == d)
        pairs = cKDTree(points[rows]).query_pairs(radius, output_type="ndarray")
        graph = coo_matrix(
            (np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(rows), len(rows))
        )
        n, labels = connected_components(graph, directed=False)
        pieces[rows] = offset + labels
        offset += n
    return _absorb_small(points, pieces, min_points)


def _absorb_small(
    points: NDArray[np.float64], pieces: NDArray[np.int64], min_points: int
) -> NDArray[np.int64]:
    """Pieces with fewer than ``min_points`` points join the piece of their nearest point in a
    large one (sparse walls fall into specks at the contact radius); numbered ``0..P-1``."""
    sizes = np.bincount(pieces)
    large = sizes[pieces] >= min_points
    if not large.any():
        return np.zeros(len(pieces), dtype=np.int64)
    small = np.flatnonzero(~large)
    if len(small):
        kept = np.flatnonzero(large)
        _, nearest = cKDTree(points[kept]).query(points[small])
        pieces = pieces.copy()
        pieces[small] = pieces[kept[nearest]]
    out: NDArray[np.int64] = np.unique(pieces, return_inverse=True)[1].reshape(-1)
    return out
