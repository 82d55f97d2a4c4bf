"""Object instances from clusters: fragments of one object merge, stuff is one region per surface.

Clustering at one scale cuts objects into fragments (a mug's handle, a teddy's head) and leaves
clusters no view labelled. Objects are built from the classified clusters in three steps, each
with a documented threshold of :class:`~dcseg.assign.config.AssignConfig`:

1. **Adjacency.** Two clusters touch when at least ``min_contacts`` of their Gaussians have a
   Gaussian of the other among their ``neighbours`` nearest within the contact radius.
2. **Unlabelled fragments** take the class their touching labelled neighbours hold most
   contacts with (weighted with their own pooled class evidence) and join the neighbour of that
   class they touch most; in passes, so that a chain of fragments (a wall that clustering cut
   into hundreds of pieces) is reached piece by piece. Fragments never connected to a labelled
   cluster are left out of the instance list.
3. **Merging** (union-find): touching clusters of the same class whose feature centres
   (cosine >= ``merge_min_cosine``) and class votes over views (cosine >=
   ``merge_min_vote_cosine``) agree are one object. Stuff classes (walls, floor ...) ignore
   features: touching clusters of the class merge when they are coplanar (their planes' normals
   agree and each lies in the other's plane), so every connected surface is one region and
   walls meeting at a corner are two.

4. **Near objects** (``merge_near``): objects of one (non-stuff) class whose nearest Gaussians
   are within the contact radius and whose mean features agree (cosine >= ``near_min_cosine``)
   are one object: pieces of a ball or a duck that touch only along a seam of a few Gaussians,
   or not at all, which the cluster contacts of step 3 miss.

Objects and regions with fewer than ``min_instance_gaussians`` Gaussians dissolve, and so do
objects far smaller than the largest object of their class (``min_fragment_share`` of its
size: a ball's loose patches next to two whole balls); their Gaussians, and
labelled Gaussians outside every cluster, join the object or region of a near
Gaussian of their class, or stay out of the instance list (they keep their class).

Steps 1-2 live in :mod:`dcseg.assign.adoption`, the plane geometry of stuff surfaces in
:mod:`dcseg.assign.planes`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.cluster.hierarchy import DisjointSet
from scipy.spatial import cKDTree

from dcseg.assign.adoption import Fragments
from dcseg.assign.config import AssignConfig
from dcseg.assign.planes import cluster_planes, coplanar, split_stuff_planes


@dataclass(frozen=True)
class Instances:
    """Object instances of N Gaussians made of K clusters (arrays are read-only).

    Attributes:
        ids: ``[N]`` int64 instance per Gaussian in ``0..M-1``, -1 = none.
        classes: ``[M]`` int64 class of each instance.
        scores: ``[M]`` float64 mean assignment score of its clusters' Gaussians (0 for
            stuff regions and adopted fragments without a vote).
        of_cluster: ``[K]`` int64 instance holding most of each cluster's Gaussians, -1 = none.
    """

    ids: NDArray[np.int64]
    classes: NDArray[np.int64]
    scores: NDArray[np.float64]
    of_cluster: NDArray[np.int64]

    def __post_init__(self) -> None:
        for array in (self.ids, self.classes, self.scores, self.of_cluster):
            array.flags.writeable = False

    @property
    def n_instances(self) -> int:
        return int(self.classes.shape[0])

    def of_classes(self, labels: NDArray[np.int64]) -> Instances:
        """These instances once Gaussians whose class (``labels``, ``[N]``) is no longer their
        instance's class have left it (instance -1); the instances themselves stay.

        Example:
            >>> one = Instances(np.array([0, 0, -1]), np.array([2]), np.ones(1), np.zeros(1, int))
            >>> one.of_classes(np.array([2, 1, 2])).ids.tolist()
            [0, -1, -1]
        """
        if np.shape(labels) != self.ids.shape:
            raise ValueError(f"labels {np.shape(labels)} must be [N] = {self.ids.shape}")
        own = np.append(self.classes, -1)[self.ids]  # id -1 reads the appended -1
        ids = np.where((self.ids >= 0) & (own != np.asarray(labels)), -1, self.ids)
        return Instances(ids, self.classes.copy(), self.scores.copy(), self.of_cluster.copy())


def _cosine(x: NDArray[np.float64], a: NDArray[np.int64], b: NDArray[np.int64]) -> Any:
    norms = np.linalg.norm(x, axis=1)
    dots = np.einsum("ij,ij->i", x[a], x[b])
    return dots / np.maximum(norms[a] * norms[b], 1e-12)


def merge_clusters(
    classes: NDArray[np.int64],
    parent: NDArray[np.int64],
    pairs: NDArray[np.int64],
    counts: NDArray[np.int64],
    centers: NDArray[np.floating[Any]],
    votes: NDArray[np.float64],
    stuff: NDArray[np.bool_],
    cfg: AssignConfig,
    planes: tuple[NDArray[np.float64], NDArray[np.float64]],
) -> NDArray[np.int64]:
    """Union-find over clusters (step 3): ``[K]`` root cluster of each labelled cluster, -1 else.

    Adopted clusters join their ``parent``; touching same-class clusters merge when features
    and votes agree, or, for stuff classes, when they are coplanar
    (:func:`~dcseg.assign.planes.coplanar`; ``planes`` from
    :func:`~dcseg.assign.planes.cluster_planes`).
    """
    k = len(classes)
    sets = DisjointSet(range(k))
    for child in np.flatnonzero(parent >= 0):
        sets.merge(int(child), int(parent[child]))
    a, b = pairs[:, 0], pairs[:, 1]
    same = (counts >= cfg.min_contacts) & (classes[a] >= 0) & (classes[a] == classes[b])
    a, b = a[same], b[same]
    features = np.asarray(centers, dtype=np.float64)
    alike = _cosine(features, a, b) >= cfg.merge_min_cosine
    alike &= _cosine(votes, a, b) >= cfg.merge_min_vote_cosine
    ok = np.where(stuff[classes[a]], coplanar(*planes, a, b, cfg), alike)
    for x, y in zip(a[ok], b[ok], strict=True):
        sets.merge(int(x), int(y))
    roots = np.array([sets[i] for i in range(k)], dtype=np.int64)
    return np.where(classes >= 0, roots, -1)


def _attach_loose(
    means: NDArray[np.float64],
    semantic: NDArray[np.int64],
    group: NDArray[np.int64],
    radius: float,
    neighbours: int,
) -> NDArray[np.int64]:
    """Labelled Gaussians without a group take the group of a near same-class Gaussian."""
    out = group.copy()
    loose = np.flatnonzero((semantic >= 0) & (group < 0))
    placed = np.flatnonzero(group >= 0)
    if len(loose) == 0 or len(placed) == 0:
        return out
    k = min(neighbours, len(placed))
    _, idx = cKDTree(means[placed]).query(means[loose], k=k, distance_upper_bound=radius)
    idx = np.asarray(idx, dtype=np.int64).reshape(len(loose), k)
    found = idx < len(placed)
    cand = placed[np.where(found, idx, 0)]
    match = found & (semantic[cand] == semantic[loose, None])
    first = match.argmax(axis=1)
    hit = match[np.arange(len(loose)), first]
    out[loose[hit]] = group[cand[hit, first[hit]]]
    return out


def object_instances(
    means: NDArray[np.floating[Any]],
    cluster_labels: NDArray[np.int64],
    semantic: NDArray[np.int64],
    fragments: Fragments,
    centers: NDArray[np.floating[Any]],
    votes: NDArray[np.float64],
    cluster_scores: NDArray[np.float64],
    stuff_ids: Sequence[int],
    radius: float,
    cfg: AssignConfig,
) -> Instances:
    """Step 3: objects and stuff regions (see the module docstring).

    Args:
        means: ``[N, 3]`` Gaussian centres.
        cluster_labels: ``[N]`` cluster per Gaussian, -1 = noise.
        semantic: ``[N]`` final class per Gaussian (after completion), -1 = none.
        fragments: from :func:`~dcseg.assign.adoption.adopt_fragments`.
        centers: ``[K, D]`` unit feature centres of the clusters.
        votes: ``[K, C]`` the assignment's summed IoU votes.
        cluster_scores: ``[K]`` the assignment's scores.
        stuff_ids: class indices that are stuff.
        radius: contact radius (world units).
        cfg: the thresholds.
    """
    xyz = np.asarray(means, dtype=np.float64).reshape(-1, 3)
    labels = np.asarray(cluster_labels, dtype=np.int64)
    k, n_classes = votes.shape
    stuff = np.zeros(max(n_classes, int(semantic.max(initial=-1)) + 1), dtype=bool)
    stuff[[s for s in stuff_ids if 0 <= s < len(stuff)]] = True
    f = fragments
    planes = cluster_planes(xyz, labels, k)
    roots = merge_clusters(
        f.classes, f.parent, f.pairs, f.counts, centers, votes, stuff, cfg, planes
    )
    group = np.where(labels >= 0, roots[np.maximum(labels, 0)], -1) if k else labels.copy()
    own = (labels >= 0) & (semantic == (f.classes[np.maximum(labels, 0)] if k else -2))
    group = np.where((semantic >= 0) & own, group, -1)
    if cfg.split_stuff_planes:
        group = split_stuff_planes(xyz, group, semantic, stuff, radius, cfg)
    if cfg.merge_near and k:
        features = np.asarray(centers, dtype=np.float64)[np.maximum(labels, 0)]
        group = merge_near_objects(xyz, group, semantic, stuff, features, radius, cfg)
    group = _drop_small(group, cfg.min_instance_gaussians)
    group = drop_fragments(group, semantic, stuff, cfg.min_fragment_share)
    group = _attach_loose(xyz, semantic, group, radius, cfg.neighbours)
    scores = cluster_scores[np.maximum(labels, 0)] if k else np.zeros(len(labels))
    scores = np.where(labels >= 0, scores, 0.0)
    return number_groups(group, semantic, scores, labels, k, cfg.min_instance_gaussians)


def merge_near_objects(
    means: NDArray[np.float64],
    group: NDArray[np.int64],
    semantic: NDArray[np.int64],
    stuff: NDArray[np.bool_],
    features: NDArray[np.float64],
    radius: float,
    cfg: AssignConfig,
) -> NDArray[np.int64]:
    """Same-class objects within ``radius`` of each other with agreeing features merge (step 4).

    Args:
        means: ``[N, 3]`` Gaussian centres.
        group: ``[N]`` object key per Gaussian, -1 = none.
        semantic: ``[N]`` class per Gaussian (a group's class is its first Gaussian's).
        stuff: ``[C]`` True for stuff classes, which never merge here.
        features: ``[N, D]`` feature per Gaussian (its cluster's centre).
        radius: the contact radius: the largest gap between two objects that merge.
        cfg: ``near_min_cosine``, the smallest cosine of the two objects' mean features.
    """
    inside = np.flatnonzero(group >= 0)
    keys, first, inverse = np.unique(group[inside], return_index=True, return_inverse=True)
    if len(keys) < 2:
        return group
    classes = semantic[inside[first]]
    solid = ~((classes >= 0) & (classes < len(stuff)) & stuff[np.clip(classes, 0, len(stuff) - 1)])
    mean = np.zeros((len(keys), features.shape[1]))
    np.add.at(mean, inverse.reshape(-1), features[inside])  # sums: the cosine ignores scale
    sets = DisjointSet(keys.tolist())
    for i, j in _same_class_pairs(classes, solid):
        cosine = float(_cosine(mean, np.array([i]), np.array([j]))[0])
        if cosine >= cfg.near_min_cosine and _gap(means, group, keys[i], keys[j]) <= radius:
            sets.merge(int(keys[i]), int(keys[j]))
    roots = np.array([sets[int(key)] for key in keys], dtype=np.int64)
    out = group.copy()
    out[inside] = roots[inverse.reshape(-1)]
    return out


def _same_class_pairs(
    classes: NDArray[np.int64], solid: NDArray[np.bool_]
) -> list[tuple[int, int]]:
    """Index pairs ``i < j`` of non-stuff groups of one class."""
    return [
        (i, j)
        for i in range(len(classes))
        for j in range(i + 1, len(classes))
        if solid[i] and classes[i] == classes[j]
    ]


def _gap(means: NDArray[np.float64], group: NDArray[np.int64], a: int, b: int) -> float:
    """The smallest distance between a Gaussian of group ``a`` and one of group ``b``."""
    distances, _ = cKDTree(means[group == a]).query(means[group == b], k=1)
    return float(np.min(distances))


def _drop_small(group: NDArray[np.int64], min_size: int) -> NDArray[np.int64]:
    """Groups with fewer than ``min_size`` Gaussians dissolve (-1)."""
    inside = group >= 0
    _, inverse, sizes = np.unique(group[inside], return_inverse=True, return_counts=True)
    out = group.copy()
    out[inside] = np.where(sizes[inverse] >= min_size, group[inside], -1)
    return out


def drop_fragments(
    group: NDArray[np.int64],
    semantic: NDArray[np.int64],
    stuff: NDArray[np.bool_],
    share: float,
) -> NDArray[np.int64]:
    """Objects smaller than ``share`` of the largest object of their class dissolve (-1).

    Args:
        group: ``[N]`` object key per Gaussian, -1 = none.
        semantic: ``[N]`` class per Gaussian; an object's class is its first Gaussian's
            (every Gaussian of a group carries the group's class here).
        stuff: ``[C]`` True for stuff classes, whose regions are never fragments.
        share: the share of the largest object of the class below which an object dissolves;
            0 = off.
    """
    inside = np.flatnonzero(group >= 0)
    if share <= 0 or len(inside) == 0:
        return group
    keys, first, inverse, sizes = np.unique(
        group[inside], return_index=True, return_inverse=True, return_counts=True
    )
    classes = semantic[inside[first]]
    small = np.zeros(len(keys), dtype=bool)
    for cls in np.unique(classes):
        if 0 <= cls < len(stuff) and stuff[cls]:
            continue
        of_class = classes == cls
        small |= of_class & (sizes < share * sizes[of_class].max())
    out = group.copy()
    out[inside[small[inverse]]] = -1
    return out


def number_groups(
    group: NDArray[np.int64],
    semantic: NDArray[np.int64],
    scores: NDArray[np.float64],
    labels: NDArray[np.int64],
    k: int,
    min_size: int,
) -> Instances:
    """Instances ``0..M-1`` from group keys; groups below ``min_size`` Gaussians are left out.

    An instance's class is the class most of its Gaussians carry."""
    ids = np.full(len(group), -1, dtype=np.int64)
    inside = group >= 0
    _, inverse, sizes = np.unique(group[inside], return_inverse=True, return_counts=True)
    kept = sizes >= min_size
    ids[inside] = np.where(kept, np.cumsum(kept) - 1, -1)[inverse]
    m = int(kept.sum())
    inside = ids >= 0
    c = int(semantic.max(initial=-1)) + 1
    table = np.bincount(ids[inside] * c + semantic[inside], minlength=m * c).reshape(m, c)
    classes = table.argmax(axis=1).astype(np.int64) if c else np.zeros(m, dtype=np.int64)
    size = np.bincount(ids[inside], minlength=m)
    total = np.bincount(ids[inside], weights=scores[inside], minlength=m)
    mean_score = np.divide(total, size, out=np.zeros(m), where=size > 0)
    return Instances(ids, classes, mean_score, _of_cluster(ids, labels, k))


def _of_cluster(ids: NDArray[np.int64], labels: NDArray[np.int64], k: int) -> Any:
    out = np.full(k, -1, dtype=np.int64)
    both = (ids >= 0) & (labels >= 0)
    if both.any():
        m = int(ids.max()) + 1
        table = np.bincount(labels[both] * m + ids[both], minlength=k * m).reshape(k, m)
        out = np.where(table.sum(axis=1) > 0, table.argmax(axis=1), -1)
    return out
