"""Fit HDBSCAN on a seeded sample of Gaussian features, then assign every Gaussian by cosine.

This is the fit/predict split of the paper code (method doc §4): fit on a sample, centres =
normalised sample means, every Gaussian joins its most similar centre above a floor.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from dcseg.cluster.backends import Clusterer, make_clusterer
from dcseg.cluster.config import ClusterConfig

if TYPE_CHECKING:
    from torch import Tensor

    ArrayOrTensor = NDArray[Any] | Tensor
else:
    ArrayOrTensor = Any

_ASSIGN_CHUNK = 65536
"""Gaussians scored per block in :func:`assign_to_centers` (bounds memory to chunk x K)."""


@dataclass(frozen=True)
class Clustering:
    """Instance clusters of N Gaussians (arrays are read-only).

    Attributes:
        labels: ``[N]`` int64 cluster id in ``0..K-1``; -1 = noise / unassigned (scikit-learn's
            sentinel convention).
        centers: ``[K, D]`` float32 unit-norm cluster centres in feature space.
        scores: ``[N]`` float32 cosine similarity of each Gaussian to its best-matching centre
            at assignment time. Also filled for Gaussians that ended up -1 (below the
            similarity floor, or dropped as 3D outliers); 0 when there are no clusters.
    """

    labels: NDArray[np.int64]
    centers: NDArray[np.float32]
    scores: NDArray[np.float32]

    def __post_init__(self) -> None:
        for array in (self.labels, self.centers, self.scores):
            array.flags.writeable = False

    @property
    def n_clusters(self) -> int:
        """K, the number of clusters."""
        return int(self.centers.shape[0])


def as_numpy(x: ArrayOrTensor, dtype: type[np.generic]) -> NDArray[Any]:
    """A numpy copy-or-view of an array or (CPU or device) torch tensor, cast to ``dtype``."""
    if hasattr(x, "detach"):  # torch.Tensor, without importing torch
        x = x.detach().cpu().numpy()
    return np.asarray(x, dtype=dtype)


def l2_normalize(x: NDArray[np.float32], eps: float = 1e-12) -> NDArray[np.float32]:
    """Rows of ``x`` ``[N, D]`` scaled to unit L2 norm; all-zero rows stay zero."""
    norms = np.linalg.norm(x, axis=1, keepdims=True)
    return np.asarray(x / np.maximum(norms, eps), dtype=np.float32)


def sample_indices(n: int, cfg: ClusterConfig) -> NDArray[np.int64]:
    """Sorted, seeded random subset of ``range(n)`` that HDBSCAN is fitted on.

    Size: ``sample_fraction * n`` clipped to ``[min(n, min_sample_size), min(n, max_sample_size)]``.
    """
    size = round(cfg.sample_fraction * n)
    size = int(np.clip(size, min(n, cfg.min_sample_size), min(n, cfg.max_sample_size)))
    rng = np.random.default_rng(cfg.seed)
    return np.sort(rng.choice(n, size=size, replace=False)).astype(np.int64)


def label_means(
    x: NDArray[np.float32], labels: NDArray[np.int64], n_labels: int
) -> NDArray[np.float32]:
    """Unit-norm mean of the rows of ``x`` ``[S, D]`` per label ``0..n_labels-1`` -> ``[K, D]``.

    Rows labelled -1 are ignored; labels without rows are dropped from the result.
    """
    keep = labels >= 0
    sums = np.zeros((n_labels, x.shape[1]), dtype=np.float64)
    np.add.at(sums, labels[keep], x[keep])
    counts = np.bincount(labels[keep], minlength=n_labels)
    return l2_normalize(sums[counts > 0].astype(np.float32))


def refit_unassigned(
    x: NDArray[np.float32],
    labels: NDArray[np.int64],
    scores: NDArray[np.float32],
    centers: NDArray[np.float32],
    cfg: ClusterConfig,
    *,
    clusterer: Clusterer | None = None,
) -> tuple[NDArray[np.int64], NDArray[np.float32], NDArray[np.float32]]:
    """Second HDBSCAN pass over the Gaussians no centre claimed (``labels == -1``).

    Objects with a few dozen Gaussians get a handful of sample points and no centre of their
    own in the first pass; their Gaussians then sit far from every centre. Fitting again on
    them alone (the same sampling rule and HDBSCAN settings) finds those objects; the new
    centres are appended after the first pass's and only unassigned Gaussians can join them.

    Returns:
        Updated ``labels [N]``, ``scores [N]`` and ``centers [K + K2, D]`` (new arrays).
    """
    pool = np.flatnonzero(labels < 0)
    extra = fit_clusters(x[pool], cfg, clusterer=clusterer)
    if extra.shape[0] == 0:
        return labels, scores, centers
    sub_labels, sub_scores = assign_to_centers(x[pool], extra, cfg.min_similarity)
    labels, scores = labels.copy(), scores.copy()
    labels[pool] = np.where(sub_labels >= 0, sub_labels + len(centers), -1)
    scores[pool] = np.maximum(scores[pool], sub_scores)
    return labels, scores, np.concatenate([centers, extra]).astype(np.float32)


def fit_clusters(
    x: NDArray[np.float32], cfg: ClusterConfig, *, clusterer: Clusterer | None = None
) -> NDArray[np.float32]:
    """Fit HDBSCAN on a seeded sample of unit-norm features; return the cluster centres.

    Args:
        x: ``[N, D]`` L2-normalised features (Euclidean distance is monotone in cosine).
        cfg: clustering parameters (sample size, HDBSCAN settings, seed).
        clusterer: overrides the backend named by ``cfg.clusterer``.

    Returns:
        ``[K, D]`` float32 unit-norm centres (means of the sample's features per HDBSCAN
        label, noise excluded); ``K = 0`` when HDBSCAN finds no cluster or the sample is
        smaller than ``min_cluster_size``.
    """
    idx = sample_indices(len(x), cfg)
    if len(idx) < max(cfg.min_cluster_size, 2):
        return np.zeros((0, x.shape[1]), dtype=np.float32)
    clusterer = clusterer or make_clusterer(cfg)
    sample = np.ascontiguousarray(x[idx], dtype=np.float64)
    labels = clusterer.fit_predict(sample)
    return label_means(x[idx], labels, int(labels.max(initial=-1)) + 1)


def assign_to_centers(
    x: NDArray[np.float32], centers: NDArray[np.float32], min_similarity: float
) -> tuple[NDArray[np.int64], NDArray[np.float32]]:
    """Label every feature with its most similar centre (cosine), if similar enough.

    Args:
        x: ``[N, D]`` unit-norm features.
        centers: ``[K, D]`` unit-norm centres.
        min_similarity: features whose best cosine is below this get label -1.

    Returns:
        ``labels [N]`` int64 (argmax centre, -1 below the floor; ties -> lowest index) and
        ``scores [N]`` float32 best cosine (0 when ``K = 0``).
    """
    n = len(x)
    labels = np.full(n, -1, dtype=np.int64)
    scores = np.zeros(n, dtype=np.float32)
    if len(centers) == 0:
        return labels, scores
    for start in range(0, n, _ASSIGN_CHUNK):
        block = x[start : start + _ASSIGN_CHUNK] @ centers.T
        labels[start : start + _ASSIGN_CHUNK] = block.argmax(axis=1)
        scores[start : start + _ASSIGN_CHUNK] = block.max(axis=1)
    labels[scores < min_similarity] = -1
    return labels, scores
