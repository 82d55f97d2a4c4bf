"""3D outlier removal (method doc Part B.6): drop small, disconnected fragments of clusters.

Each cluster's Gaussian centres form a radius graph; connected components that are too small
(by count or by weight share) become noise. Memory is O(N).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

_SPACING_QUERIES = 100_000
"""At most this many Gaussians are queried to estimate the median nearest-neighbour spacing."""


def adaptive_radius(positions: NDArray[np.float64], factor: float, seed: int = 0) -> float:
    """``factor`` x the median nearest-neighbour distance between Gaussian centres.

    Args:
        positions: ``[N, 3]`` Gaussian centres.
        factor: multiplier (e.g. 3.0).
        seed: seeds the subset of at most 100 000 centres whose spacing is measured.

    Returns:
        The radius; 0.0 when fewer than two distinct centres exist.
    """
    n = len(positions)
    if n < 2:
        return 0.0
    tree = cKDTree(positions)
    queries = positions
    if n > _SPACING_QUERIES:
        rng = np.random.default_rng(seed)
        queries = positions[rng.choice(n, size=_SPACING_QUERIES, replace=False)]
    dist, _ = tree.query(queries, k=2)
    positive = dist[:, 1][dist[:, 1] > 0]
    return float(factor * np.median(positive)) if positive.size else 0.0


def _fragments(
    comp: NDArray[np.int64],
    labels: NDArray[np.int64],
    weights: NDArray[np.float64],
    min_size: int,
    min_fraction: float,
) -> NDArray[np.bool_]:
    """Per Gaussian: is its component a fragment (too few Gaussians or too light)?

    The weight threshold is relative to the cluster's heaviest component, which is therefore
    never dropped for weight: a cluster whose graph falls apart into many similar pieces keeps
    them, and only fragments much lighter than its main body go. A cluster whose total weight
    is 0 compares Gaussian counts instead.
    """
    member = comp >= 0
    sizes = np.bincount(comp[member])
    comp_weight = np.bincount(comp[member], weights=weights[member], minlength=len(sizes))
    comp_cluster = np.zeros(len(sizes), dtype=np.int64)
    comp_cluster[comp[member]] = labels[member]
    n_clusters = int(labels.max()) + 1
    cluster_weight = np.bincount(comp_cluster, weights=comp_weight, minlength=n_clusters)
    measure = np.where(cluster_weight[comp_cluster] > 0, comp_weight, sizes.astype(np.float64))
    heaviest = np.zeros(n_clusters)
    np.maximum.at(heaviest, comp_cluster, measure)
    small = (sizes < min_size) | (measure < min_fraction * heaviest[comp_cluster])
    return member & small[np.maximum(comp, 0)]


def remove_outliers_3d(
    positions: NDArray[np.float64],
    labels: NDArray[np.int64],
    weights: NDArray[np.float64],
    *,
    radius: float,
    min_component_size: int,
    min_component_fraction: float,
) -> NDArray[np.int64]:
    """Set Gaussians in small, disconnected fragments of their cluster to -1.

    For every cluster, its Gaussian centres are linked when closer than ``radius``
    (:func:`~dcseg.cluster.components.cluster_components`); each connected component with
    fewer than ``min_component_size`` Gaussians, or lighter than ``min_component_fraction`` x
    the weight of the cluster's heaviest component, is dropped. Cluster ids are not re-indexed
    here (a cluster may become empty).

    Args:
        positions: ``[N, 3]`` Gaussian centres.
        labels: ``[N]`` int64 cluster ids, -1 = noise (left untouched).
        weights: ``[N]`` non-negative weights, e.g. activated opacity. A cluster whose total
            weight is 0 uses Gaussian counts instead.
        radius: graph radius in world units (> 0).
        min_component_size: minimum Gaussians per kept component.
        min_component_fraction: minimum weight of a kept component, relative to the cluster's
            heaviest component.

    Returns:
        ``[N]`` int64 labels with the dropped Gaussians set to -1 (a new array).
    """
    if radius <= 0:
        raise ValueError(f"radius must be > 0, got {radius}")
    out = labels.copy()
    if not np.any(labels >= 0):
        return out
    from dcseg.cluster.components import cluster_components  # numba: not in the API image

    comp = cluster_components(positions, labels, radius)
    out[_fragments(comp, labels, weights, min_component_size, min_component_fraction)] = -1
    return out


def compact_labels(
    labels: NDArray[np.int64], centers: NDArray[np.float32]
) -> tuple[NDArray[np.int64], NDArray[np.float32]]:
    """Remove clusters without members; re-index the rest to ``0..K'-1`` keeping their order.

    Args:
        labels: ``[N]`` int64 cluster ids, -1 = noise.
        centers: ``[K, D]`` centres indexed by the old ids.

    Returns:
        ``labels [N]`` (new ids, -1 kept) and ``centers [K', D]``.
    """
    if len(centers) == 0:
        return labels.copy(), centers
    used = np.bincount(labels[labels >= 0], minlength=len(centers)) > 0
    new_id = np.cumsum(used) - 1
    out = np.where(labels >= 0, new_id[np.maximum(labels, 0)], -1).astype(np.int64)
    return out, centers[used]
