"""Stage: affinity features of Gaussians -> instance clusters (method doc §4, Part B.6).

Entry point: :func:`cluster_features`. Importing this package does not import torch, HDBSCAN,
scikit-learn or numba (the API image has none of them); they are imported when clustering runs.
"""

from dcseg.cluster.backends import (
    CLUSTERERS,
    Clusterer,
    HdbscanClusterer,
    SklearnHdbscanClusterer,
    make_clusterer,
)
from dcseg.cluster.config import ClusterConfig
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
