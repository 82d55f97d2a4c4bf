"""Stage: affinity features of Gaussians -> instance clusters (method doc §4, Part B.6).

Entry point: :func:`cluster_features`. Importing this package does not import torch, HDBSCAN,
scikit-learn, scipy or numba (the API image has none of them; the exports are resolved lazily,
PEP 562); they are imported when clustering runs.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from dcseg._lazy import lazy_exports
from dcseg.cluster.config import ClusterConfig

if TYPE_CHECKING:
    from dcseg.cluster.backends import (
        CLUSTERERS,
        Clusterer,
        HdbscanClusterer,
        SklearnHdbscanClusterer,
        make_clusterer,
    )
    from dcseg.cluster.features import Clustering, assign_to_centers, fit_clusters
    from dcseg.cluster.outliers import adaptive_radius, compact_labels, remove_outliers_3d
    from dcseg.cluster.stage import cluster_features

__all__ = [
    "CLUSTERERS",
    "ClusterConfig",
    "Clusterer",
    "Clustering",
    "HdbscanClusterer",
    "SklearnHdbscanClusterer",
    "adaptive_radius",
    "assign_to_centers",
    "cluster_features",
    "compact_labels",
    "fit_clusters",
    "make_clusterer",
    "remove_outliers_3d",
]

_HOME = {
    "CLUSTERERS": "dcseg.cluster.backends",
    "Clusterer": "dcseg.cluster.backends",
    "Clustering": "dcseg.cluster.features",
    "HdbscanClusterer": "dcseg.cluster.backends",
    "SklearnHdbscanClusterer": "dcseg.cluster.backends",
    "adaptive_radius": "dcseg.cluster.outliers",
    "assign_to_centers": "dcseg.cluster.features",
    "cluster_features": "dcseg.cluster.stage",
    "compact_labels": "dcseg.cluster.outliers",
    "fit_clusters": "dcseg.cluster.features",
    "make_clusterer": "dcseg.cluster.backends",
    "remove_outliers_3d": "dcseg.cluster.outliers",
}

__getattr__, __dir__ = lazy_exports(__name__, _HOME, __all__)
