"""Rings of a support surface that an object's cluster took: give them back to the support.

A segmenter prompted with an object's box (Grounded-SAM style) or painting coarse class maps
takes a ring of the table or floor round the object's base into the object's mask, in every
view: the part of the support next to the base lies in every box. The affinity features then
learn the ring with the object, and the votes and each Gaussian's own evidence name it the
object, so no vote can undo it. Geometry can: the ring continues the support's plane, the
object rises out of it.

:func:`release_rings` moves a Gaussian of an object's cluster to a bigger neighbouring cluster
(the support) when it lies in the support's local plane and its own disc lies flat in that
plane; rounds grow the support outwards over the ring, a Gaussian moved before counting
where it meets the plane it joined (so rounds cannot climb the side of a low object, a block
lying flat, a centimetre a round). Then the moves are judged (:func:`_judge_moves`): what
the object's body surrounds (a tray's bottom within its rim; bodies of other classes count
only close by) goes back to it; a cluster whose moved part sits above the support's plane
rather than about it (a block lying flat) keeps it all; and so does a cluster that would lose
more than ``AssignConfig.ring_max_share`` of its Gaussians with no body of its class beside
it (a poster on a wall, a rug).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from dcseg.assign.config import AssignConfig
from dcseg.assign.planes import cluster_planes

RING_MIN_NEIGHBOURS = 4
"""Support Gaussians within ``ring_radius`` needed to fit the support's local plane."""

RING_MIN_AGREEMENT = 0.8
"""Smallest agreement of the support neighbours' disc normals (the top eigenvalue of their
mean outer product: 1 = all parallel): a support that is not locally flat (a ball under a
smaller object) has no plane to continue. Disc normals, not the spread of the centres: the
centres scatter about a centimetre round the surface, as much as a 5 cm patch is wide."""

RING_MAX_RISE = 0.5
"""Largest median offset above the support's plane (as a share of ``ring_plane_tol``) of
the Gaussians a cluster would give up: a higher one is a raised face of a thin object (a
block lying flat, a tray's bottom), and the cluster keeps them all."""

RING_NEIGHBOURS = 48
"""Nearest Gaussians (within ``ring_radius``) looked at per candidate: enough for a local
plane; the support grows over a wide ring in rounds."""

RING_BLOCK = 32_768
"""Candidates whose neighbours are looked up at once (a ``[block, RING_NEIGHBOURS]`` table)."""

RING_SIZE_RATIO = 2.0
"""A support cluster holds at least this many times the object cluster's Gaussians."""

RING_ENCLOSE_RADIUS = 0.4
"""Distance (metres) within which a body of its cluster's class must surround a moved
Gaussian to keep it (:func:`_judge_moves`): a large tray's width, so that its far rim counts.
Bodies of other classes count within ``AssignConfig.ring_radius`` only."""

RING_BODY_POINTS = 4096
"""Body Gaussians round one cluster's moves that the sector test looks at (:func:`_thinned`)."""

RING_MAX_GAP = np.pi / 2
"""Widest empty sector (radians) round a Gaussian that its object's body still encloses."""

Pairs = tuple[NDArray[np.int64], NDArray[np.int64]]
"""``(candidate, neighbour)`` index pairs: candidate positions and Gaussian indices."""


@dataclass(frozen=True)
class _Cloud:
    """What every round looks at: the Gaussians' centres ``[N, 3]``, disc normals ``[N, 3]``
    and their tree; the clusters' sizes ``[K]`` (before any move), classes ``[K]`` and
    centres ``[K, 3]``."""

    means: NDArray[np.float64]
    normals: NDArray[np.float64]
    tree: cKDTree
    sizes: NDArray[np.int64]
    classes: NDArray[np.int64]
    centres: NDArray[np.float64]


def release_rings(
    means: NDArray[np.float64],
    normals: NDArray[np.float64],
    labels: NDArray[np.int64],
    classes: NDArray[np.int64],
    stuff: Sequence[int],
    cfg: AssignConfig,
) -> tuple[NDArray[np.int64], int]:
    """Move the support rings of object clusters to their supports.

    Args:
        means: ``[N, 3]`` Gaussian centres.
        normals: ``[N, 3]`` unit normal of each Gaussian's disc (its shortest axis).
        labels: ``[N]`` cluster per Gaussian, -1 = noise.
        classes: ``[K]`` class per cluster, -1 = unlabelled.
        stuff: stuff class ids: their clusters are supports, never objects.
        cfg: ``ring_plane_tol`` (0 = off), ``ring_radius``, ``ring_min_cosine``,
            ``ring_max_share``, ``ring_rounds``.

    Returns:
        The new ``[N]`` cluster per Gaussian and how many Gaussians moved.

    Example:
        >>> xy = np.stack(np.meshgrid(np.arange(10.0), np.arange(10.0)), -1).reshape(-1, 2)
        >>> table = np.c_[xy * 0.02, np.zeros(100)]
        >>> post = np.c_[np.full(8, 0.09), np.full(8, 0.09), 0.02 * np.arange(1.0, 9.0)]
        >>> means = np.concatenate([table, post])
        >>> normals = np.tile([0.0, 0.0, 1.0], (108, 1)); normals[100:] = [1.0, 0.0, 0.0]
        >>> labels = np.r_[np.zeros(100, int), np.ones(8, int)]
        >>> labels[[44, 45, 54, 55]] = 1  # the ring round the post's base
        >>> cfg = AssignConfig(ring_plane_tol=0.01, ring_radius=0.05)
        >>> out, moved = release_rings(means, normals, labels, np.array([0, 1]), [], cfg)
        >>> moved, out[[44, 45, 54, 55]].tolist(), out[100:].tolist() == [1] * 8
        (4, [0, 0, 0, 0], True)
    """
    k = len(classes)
    if cfg.ring_plane_tol <= 0 or k == 0 or not (labels >= 0).any():
        return labels, 0
    sizes = np.bincount(labels[labels >= 0], minlength=k)
    objects = (classes >= 0) & ~np.isin(classes, np.asarray(stuff, dtype=np.int64))
    out = labels.copy()
    origin = np.full(len(labels), -1, dtype=np.int64)
    planes = np.zeros((len(labels), 3))
    rises = np.zeros(len(labels))
    centres, _ = cluster_planes(means, labels, k)
    cloud = _Cloud(means, normals, cKDTree(means), sizes, classes, centres)
    feet, faces = means.copy(), normals.copy()  # moved ones: on the plane they joined
    for _ in range(cfg.ring_rounds):
        member = out >= 0
        candidates = np.flatnonzero(member & objects[np.where(member, out, 0)])
        moving, support, normal, rise = _on_support(candidates, out, (feet, faces), cloud, cfg)
        if not len(moving):
            break
        first = origin[moving] < 0
        origin[moving[first]], planes[moving[first]] = out[moving[first]], normal[first]
        rises[moving[first]] = rise[first]
        feet[moving], faces[moving] = means[moving] - rise[:, None] * normal, normal
        out[moving] = support
    back, beside = _judge_moves(means, out, origin, planes, classes, objects, cloud.tree, cfg)
    lost = np.bincount(origin[(origin >= 0) & ~back], minlength=k)
    flat = (lost > cfg.ring_max_share * sizes) & ~beside
    flat |= _raised(origin, rises, back, k) > RING_MAX_RISE * cfg.ring_plane_tol
    back |= (origin >= 0) & flat[np.maximum(origin, 0)]
    out[back] = origin[back]
    return out, int(((origin >= 0) & ~back).sum())


def _raised(
    origin: NDArray[np.int64],
    rises: NDArray[np.float64],
    back: NDArray[np.bool_],
    k: int,
) -> NDArray[np.float64]:
    """``[K]`` median signed offset (towards the cluster) of each cluster's moved Gaussians
    that stay moved (0 for none): a ring scatters about the support's plane, a raised face
    (a block's top, a tray's bottom) sits above it."""
    out = np.zeros(k)
    for c, moved in _moved_groups(np.where(back, -1, origin)):
        out[c] = float(np.median(rises[moved]))
    return out


def _judge_moves(
    means: NDArray[np.float64],
    labels: NDArray[np.int64],
    origin: NDArray[np.int64],
    planes: NDArray[np.float64],
    classes: NDArray[np.int64],
    objects: NDArray[np.bool_],
    tree: cKDTree,
    cfg: AssignConfig,
) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
    """Per moved Gaussian (``origin`` >= 0), whether the objects round it enclose it
    (``[N]``), and per cluster, whether a body of its class lies within ``ring_radius`` of
    its moved Gaussians (``[K]``).

    Heights are taken from the plane of a cluster's moved Gaussians, upwards on the side
    where most of its class's other Gaussians within :data:`RING_ENCLOSE_RADIUS` lie (a flat
    piece of a ball has the ball above it). The bodies round a moved Gaussian are the
    Gaussians of object clusters (labelled, not stuff) that did not move and stand more than
    ``ring_plane_tol`` above that plane, among the Gaussians (found with ``tree``) within
    :data:`RING_ENCLOSE_RADIUS` of the cluster's moved ones; seen along the normal, they
    enclose it when they leave no empty sector wider than :data:`RING_MAX_GAP`: bodies of
    the cluster's own class within :data:`RING_ENCLOSE_RADIUS`, or any within
    ``ring_radius``. A ring lies round an object's base, the object on one side; a tray's
    bottom lies within its rim and a ball's underside under the ball, which hold them. Other
    objects standing 10-40 cm round a ring on a cluttered table do not make it a tray's
    bottom (they did before 2026-12-07: detector layout 5 kept 214 ring Gaussians so). A
    flat cluster with Gaussians of its class more than ``2 ring_plane_tol`` off the plane
    beside it is a piece of the support that such an object's masks took (and that voted its
    class); without them it is a flat object of its own (a poster, a rug, a domino lying
    flat)."""
    back = np.zeros(len(labels), dtype=bool)
    beside = np.zeros(len(classes), dtype=bool)
    member = labels >= 0
    kept = member & (origin < 0)
    of_class = np.where(kept, classes[np.where(member, labels, 0)], -1)
    solid = kept & objects[np.where(member, labels, 0)]
    for k, moved in _moved_groups(origin):
        signs = np.sign(planes[moved] @ planes[moved[0]])  # eigenvectors: either sign
        normal = (planes[moved] * signs[:, None]).sum(axis=0)
        if not np.linalg.norm(normal) > 0:
            continue
        normal /= np.linalg.norm(normal)
        at = means[moved]
        centre = at.mean(axis=0)
        reach = float(np.linalg.norm(at - centre, axis=1).max()) + RING_ENCLOSE_RADIUS
        near = np.asarray(tree.query_ball_point(centre, reach), dtype=np.int64)
        points, same = means[near], of_class[near] == classes[k]
        height = points @ normal - float(np.median(at @ normal))
        if _below(centre, points[same], height[same]):
            normal, height = -normal, -height  # the object's body lies on the other side
        raised = solid[near] & (height > cfg.ring_plane_tol)
        axes = _plane_axes(normal)
        seen = at @ axes  # the moved Gaussians seen along the normal
        back[moved] = _enclosed(seen, _thinned(points[raised & same]) @ axes) | _enclosed(
            seen, _thinned(points[raised]) @ axes, cfg.ring_radius
        )
        own = points[same & (np.abs(height) > 2.0 * cfg.ring_plane_tol)]
        if len(own):
            gap, _ = cKDTree(own).query(at, distance_upper_bound=cfg.ring_radius)
            beside[k] = bool(np.isfinite(gap).any())
    return back, beside


def _thinned(points: NDArray[np.float64]) -> NDArray[np.float64]:
    """At most :data:`RING_BODY_POINTS` of ``points``, evenly strided: the sectors round a
    Gaussian need no more, and a dense scene would hand thousands to each of them."""
    step = -(-len(points) // RING_BODY_POINTS)
    return points[::step] if step > 1 else points


def _moved_groups(origin: NDArray[np.int64]) -> list[tuple[int, NDArray[np.int64]]]:
    """``(cluster, indices)`` of the Gaussians each cluster gave up (``origin`` >= 0), by
    cluster, in one sort rather than a pass over every Gaussian per cluster."""
    moved = np.flatnonzero(origin >= 0)
    if not len(moved):
        return []
    order = moved[np.argsort(origin[moved], kind="stable")]
    clusters, starts = np.unique(origin[order], return_index=True)
    return list(zip(clusters.tolist(), np.split(order, starts[1:]), strict=True))


def _below(
    centre: NDArray[np.float64], points: NDArray[np.float64], heights: NDArray[np.float64]
) -> bool:
    """Whether most of ``points`` within :data:`RING_ENCLOSE_RADIUS` of ``centre`` (an
    object's body round its moved Gaussians) lie below the plane (``heights`` < 0)."""
    near = np.linalg.norm(points - centre, axis=1) < RING_ENCLOSE_RADIUS
    return bool(near.any()) and float(np.median(heights[near])) < 0.0


def _enclosed(
    points: NDArray[np.float64], body: NDArray[np.float64], radius: float = RING_ENCLOSE_RADIUS
) -> NDArray[np.bool_]:
    """``[M]`` which 2D ``points`` the 2D ``body`` surrounds within ``radius``, leaving no
    empty sector wider than :data:`RING_MAX_GAP`."""
    out = np.zeros(len(points), dtype=bool)
    if not len(body):
        return out
    found = cKDTree(body).query_ball_point(points, radius)
    for i, near in enumerate(found):
        if len(near) < 3:
            continue
        step = body[near] - points[i]
        angles = np.sort(np.arctan2(step[:, 1], step[:, 0]))
        gaps = np.diff(np.r_[angles, angles[0] + 2.0 * np.pi])
        out[i] = gaps.max() < RING_MAX_GAP
    return out


def _plane_axes(normal: NDArray[np.float64]) -> NDArray[np.float64]:
    """``[3, 2]`` two unit vectors spanning the plane orthogonal to unit ``normal``."""
    helper = np.eye(3)[int(np.argmin(np.abs(normal)))]
    u = np.cross(normal, helper)
    u /= np.linalg.norm(u)
    return np.stack([u, np.cross(normal, u)], axis=1)


def _on_support(
    candidates: NDArray[np.int64],
    labels: NDArray[np.int64],
    anchors: tuple[NDArray[np.float64], NDArray[np.float64]],
    cloud: _Cloud,
    cfg: AssignConfig,
) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]:
    """The candidates lying flat in a bigger neighbouring cluster's local plane, that
    cluster, that plane's unit normal (pointing to the side of the candidate's cluster
    centre) and the candidate's signed offset along it, for each. The plane is fitted to the
    neighbours' ``anchors`` (``[N, 3]`` points and ``[N, 3]`` normals): a Gaussian moved in
    an earlier round counts as the point where it meets the plane it joined, with that
    plane's normal, so that the plane cannot climb an object's side round by round."""
    m = len(candidates)
    if m == 0:
        return candidates, candidates, np.zeros((0, 3)), np.zeros(0)
    pick, near = _support_pairs(candidates, labels, cloud, cfg.ring_radius)
    support = _most_frequent(pick, labels[near], m)
    same = labels[near] == support[pick]
    pick, near = pick[same], near[same]
    means, normals = cloud.means, cloud.normals
    feet, faces = anchors
    centroid, normal, agreement = _local_planes(pick, feet[near], faces[near], m)
    towards = np.einsum("ij,ij->i", normal, cloud.centres[labels[candidates]] - centroid)
    normal *= np.where(towards < 0, -1.0, 1.0)[:, None]  # pointing to the object's side
    enough = np.bincount(pick, minlength=m) >= RING_MIN_NEIGHBOURS
    rise = np.einsum("ij,ij->i", normal, means[candidates] - centroid)
    facing = np.abs(np.einsum("ij,ij->i", normal, normals[candidates]))
    move = enough & (agreement >= RING_MIN_AGREEMENT) & (np.abs(rise) <= cfg.ring_plane_tol)
    move &= facing >= cfg.ring_min_cosine
    return candidates[move], support[move], normal[move], rise[move]


def _support_pairs(
    candidates: NDArray[np.int64],
    labels: NDArray[np.int64],
    cloud: _Cloud,
    radius: float,
) -> Pairs:
    """Pairs of a candidate and one of its :data:`RING_NEIGHBOURS` nearest Gaussians within
    ``radius`` that lies in another labelled cluster at least :data:`RING_SIZE_RATIO` times
    the candidate's cluster; :data:`RING_BLOCK` candidates at a time (bounds the neighbour
    table on scenes of millions of Gaussians)."""
    picks, nears = [], []
    for start in range(0, len(candidates), RING_BLOCK):
        block = candidates[start : start + RING_BLOCK]
        pick, near = _block_pairs(block, labels, cloud, radius)
        picks.append(pick + start)
        nears.append(near)
    if not picks:
        return candidates[:0], candidates[:0]
    return np.concatenate(picks), np.concatenate(nears)


def _block_pairs(
    block: NDArray[np.int64], labels: NDArray[np.int64], cloud: _Cloud, radius: float
) -> Pairs:
    k = min(RING_NEIGHBOURS, len(cloud.means))
    gap, index = cloud.tree.query(cloud.means[block], k=k, distance_upper_bound=radius)
    found = np.isfinite(gap.reshape(len(block), k))
    pick = np.nonzero(found)[0].astype(np.int64)
    near = index.reshape(len(block), k)[found].astype(np.int64)
    own, other = labels[block][pick], labels[near]
    safe = np.maximum(other, 0)
    ok = (other >= 0) & (other != own) & (cloud.classes[safe] >= 0)
    ok &= cloud.sizes[safe] >= RING_SIZE_RATIO * cloud.sizes[own]
    return pick[ok], near[ok]


def _most_frequent(pick: NDArray[np.int64], values: NDArray[np.int64], m: int) -> NDArray[np.int64]:
    """``[m]`` most frequent (non-negative) value per candidate (lowest on ties), -1 for
    none."""
    out = np.full(m, -1, dtype=np.int64)
    if not len(pick):
        return out
    span = int(values.max()) + 1
    keys, counts = np.unique(pick * span + values, return_counts=True)
    who, what = keys // span, keys % span
    order = np.lexsort((what, -counts, who))
    first = np.unique(who[order], return_index=True)[1]
    out[who[order[first]]] = what[order[first]]
    return out


def _local_planes(
    pick: NDArray[np.int64],
    points: NDArray[np.float64],
    normals: NDArray[np.float64],
    m: int,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Per candidate, the centroid of its support neighbours ``points``, the unit normal their
    disc ``normals`` agree on (top eigenvector of the mean outer product, sign-free) and
    that agreement (its eigenvalue: 1 = all parallel; 0 without neighbours)."""
    count = np.maximum(np.bincount(pick, minlength=m), 1).astype(np.float64)
    centroid = np.stack([np.bincount(pick, points[:, i], m) for i in range(3)], 1) / count[:, None]
    outer = np.zeros((m, 3, 3))
    np.add.at(outer, pick, normals[:, :, None] * normals[:, None, :])
    values, vectors = np.linalg.eigh(outer / count[:, None, None])
    return centroid, vectors[:, :, 2], values[:, 2]
