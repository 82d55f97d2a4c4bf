"""Several HDBSCAN fits on independent samples; keep the one that agrees most with the others.

HDBSCAN is fitted on a random sample of the Gaussians, and which clusters it finds depends on
that sample: on the synthetic benchmark scenes one sample seed gives 59 clusters and another
319 for the same features. Fitting on ``cfg.ensemble`` samples and keeping the *medoid*
partition — the one with the highest mean adjusted Rand index to the others, measured on a
fixed subset of Gaussians — returns a typical partition instead of a random one.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from dcseg.cluster.backends import Clusterer
from dcseg.cluster.config import ClusterConfig
from dcseg.cluster.features import assign_to_centers, fit_clusters, refit_unassigned

Partition = tuple[NDArray[np.int64], NDArray[np.float32], NDArray[np.float32]]
"""``labels [N]``, ``scores [N]``, ``centers [K, D]`` of one fit."""

AGREEMENT_POINTS = 20_000
"""Gaussians (a seeded subset) on which partitions are compared."""


def fit_partition(
    x: NDArray[np.float32], cfg: ClusterConfig, clusterer: Clusterer | None
) -> Partition:
    """One fit: HDBSCAN on ``cfg.seed``'s sample, assignment, optional second pass."""
    centers = fit_clusters(x, cfg, clusterer=clusterer)
    labels, scores = assign_to_centers(x, centers, cfg.min_similarity)
    if cfg.refit_unassigned:
        labels, scores, centers = refit_unassigned(
            x, labels, scores, centers, cfg, clusterer=clusterer
        )
    return labels, scores, centers


def medoid(partitions: list[NDArray[np.int64]], seed: int) -> int:
    """Index of the partition with the highest mean adjusted Rand index to the others.

    Noise (-1) counts as one more label. Ties go to the lowest index; one partition -> 0.
    """
    if len(partitions) == 1:
        return 0
    from sklearn.metrics import adjusted_rand_score  # heavy: import on use, as HDBSCAN

    n = len(partitions[0])
    rng = np.random.default_rng(seed)
    subset = rng.choice(n, size=min(n, AGREEMENT_POINTS), replace=False)
    picked = [p[subset] for p in partitions]
    m = len(picked)
    agreement = np.zeros((m, m))
    for i in range(m):
        for j in range(i + 1, m):
            agreement[i, j] = agreement[j, i] = adjusted_rand_score(picked[i], picked[j])
    return int(np.argmax(agreement.sum(axis=1)))


def consensus_partition(
    x: NDArray[np.float32], cfg: ClusterConfig, clusterer: Clusterer | None = None
) -> Partition:
    """The medoid of ``cfg.ensemble`` fits with sample seeds ``cfg.seed, cfg.seed + 1, ...``.

    With ``cfg.ensemble == 1`` this is exactly the single fit of ``cfg.seed``.
    """
    fits = [
        fit_partition(x, replace(cfg, seed=cfg.seed + i), clusterer) for i in range(cfg.ensemble)
    ]
    return fits[medoid([labels for labels, _, _ in fits], cfg.seed)]
