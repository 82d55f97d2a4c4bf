"""HDBSCAN backends behind one :class:`Clusterer` Protocol, chosen by name from a dict registry.

Both backends receive ``min_samples`` in dcseg's meaning (the contrib package's: the number of
*other* points, see :class:`~dcseg.cluster.config.ClusterConfig`) and translate it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from dcseg.cluster.config import ClusterConfig


class Clusterer(Protocol):
    """Density clustering of a feature sample."""

    def fit_predict(self, x: NDArray[np.float64]) -> NDArray[np.int64]:
        """Cluster ``x`` ``[S, D]``; returns labels ``[S]``, -1 = noise, clusters 0..K-1."""
        ...


@dataclass(frozen=True)
class HdbscanClusterer:
    """scikit-learn-contrib ``hdbscan.HDBSCAN`` (the paper's backend), Euclidean metric."""

    min_cluster_size: int
    min_samples: int
    cluster_selection_epsilon: float

    def fit_predict(self, x: NDArray[np.float64]) -> NDArray[np.int64]:
        import hdbscan  # heavy (pulls in scikit-learn): import on use

        model = hdbscan.HDBSCAN(
            min_cluster_size=self.min_cluster_size,
            min_samples=min(self.min_samples, len(x) - 1),
            cluster_selection_epsilon=float(self.cluster_selection_epsilon),
            core_dist_n_jobs=1,
        )
        return np.asarray(model.fit(x).labels_, dtype=np.int64)


@dataclass(frozen=True)
class SklearnHdbscanClusterer:
    """``sklearn.cluster.HDBSCAN``; ``min_samples`` + 1 because scikit-learn counts the point."""

    min_cluster_size: int
    min_samples: int
    cluster_selection_epsilon: float

    def fit_predict(self, x: NDArray[np.float64]) -> NDArray[np.int64]:
        from sklearn.cluster import HDBSCAN

        model = HDBSCAN(
            min_cluster_size=self.min_cluster_size,
            min_samples=min(self.min_samples + 1, len(x)),
            cluster_selection_epsilon=float(self.cluster_selection_epsilon),
            copy=True,
        )
        return np.asarray(model.fit(x).labels_, dtype=np.int64)


def _hdbscan(cfg: ClusterConfig) -> Clusterer:
    return HdbscanClusterer(
        cfg.min_cluster_size, cfg.resolved_min_samples, cfg.cluster_selection_epsilon
    )


def _sklearn(cfg: ClusterConfig) -> Clusterer:
    return SklearnHdbscanClusterer(
        cfg.min_cluster_size, cfg.resolved_min_samples, cfg.cluster_selection_epsilon
    )


CLUSTERERS: dict[str, Callable[[ClusterConfig], Clusterer]] = {
    "hdbscan": _hdbscan,
    "sklearn": _sklearn,
}
"""Clusterer factories by :attr:`ClusterConfig.clusterer` name."""


def make_clusterer(cfg: ClusterConfig) -> Clusterer:
    """The clusterer named by ``cfg.clusterer``, configured from ``cfg``."""
    return CLUSTERERS[cfg.clusterer](cfg)
