"""The clustering stage's entry point: features -> instance clusters of Gaussians."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from dcseg.cluster.backends import Clusterer
from dcseg.cluster.config import ClusterConfig
from dcseg.cluster.ensemble import consensus_partition
from dcseg.cluster.features import ArrayOrTensor, Clustering, as_numpy, l2_normalize
from dcseg.cluster.outliers import adaptive_radius, compact_labels, remove_outliers_3d


def _checked_inputs(
    features: ArrayOrTensor, centers3d: ArrayOrTensor, weights: ArrayOrTensor | None
) -> tuple[NDArray[np.float32], NDArray[np.float64], NDArray[np.float64]]:
    x = as_numpy(features, np.float32)
    pos = as_numpy(centers3d, np.float64)
    if x.ndim != 2:
        raise ValueError(f"features must be [N, D], got shape {x.shape}")
    if pos.shape != (len(x), 3):
        raise ValueError(f"centers3d must be [{len(x)}, 3], got shape {pos.shape}")
    w = np.ones(len(x)) if weights is None else as_numpy(weights, np.float64)
    if w.shape != (len(x),):
        raise ValueError(f"weights must be [{len(x)}], got shape {w.shape}")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(pos))):
        raise ValueError("features and centers3d must be finite")
    if not (np.all(np.isfinite(w)) and np.all(w >= 0)):
        raise ValueError("weights must be finite and >= 0")
    return x, pos, w


def _drop_outliers(
    pos: NDArray[np.float64], labels: NDArray[np.int64], w: NDArray[np.float64], cfg: ClusterConfig
) -> NDArray[np.int64]:
    radius = cfg.outlier_radius or adaptive_radius(pos, cfg.radius_factor, cfg.seed)
    if radius <= 0:
        return labels
    return remove_outliers_3d(
        pos,
        labels,
        w,
        radius=radius,
        min_component_size=cfg.min_component_size,
        min_component_fraction=cfg.min_component_fraction,
    )


def cluster_features(
    features: ArrayOrTensor,
    centers3d: ArrayOrTensor,
    weights: ArrayOrTensor | None,
    cfg: ClusterConfig,
    *,
    clusterer: Clusterer | None = None,
) -> Clustering:
    """Cluster Gaussians by their (already scale-gated) affinity features.

    Steps: L2-normalise; fit HDBSCAN on a seeded sample (:func:`fit_clusters`); assign every
    Gaussian to its most similar centre above ``cfg.min_similarity``
    (:func:`assign_to_centers`); fit again on the Gaussians left unassigned
    (:func:`refit_unassigned`, when ``cfg.refit_unassigned``) — ``cfg.ensemble`` times on
    independent samples, keeping the most typical partition
    (:func:`~dcseg.cluster.ensemble.consensus_partition`); drop small disconnected 3D
    fragments of each cluster (:func:`remove_outliers_3d`); remove emptied clusters and
    re-index ``0..K-1``.
    Deterministic for a given ``cfg.seed``.

    Args:
        features: ``[N, D]`` float features (numpy array or torch tensor on any device).
        centers3d: ``[N, 3]`` Gaussian positions (world units).
        weights: ``[N]`` non-negative per-Gaussian weights for the 3D outlier test, e.g.
            activated opacity (not logits); None = all ones.
        cfg: the stage's parameters.
        clusterer: overrides the HDBSCAN backend named by ``cfg.clusterer``.

    Returns:
        :class:`Clustering` with ``labels [N]`` (-1 = noise), ``centers [K, D]``, ``scores [N]``.

    Example:
        >>> rng = np.random.default_rng(0)
        >>> feats = np.repeat(np.eye(4, dtype=np.float32), 50, axis=0)
        >>> feats += 0.01 * rng.standard_normal(feats.shape).astype(np.float32)
        >>> xyz = np.repeat(np.eye(4)[:, :3] * 10, 50, axis=0) + rng.random((200, 3))
        >>> result = cluster_features(feats, xyz, None, ClusterConfig())
        >>> result.n_clusters, result.labels.shape
        (4, (200,))
    """
    x, pos, w = _checked_inputs(features, centers3d, weights)
    x = l2_normalize(x)
    labels, scores, centers = consensus_partition(x, cfg, clusterer)
    if cfg.remove_outliers:
        labels = _drop_outliers(pos, labels, w, cfg)
    labels, centers = compact_labels(labels, centers)
    return Clustering(labels=labels, centers=centers, scores=scores)
