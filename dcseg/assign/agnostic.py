"""Objects without classes: a class-agnostic run's clusters merged into object instances.

Without class-aware masks there are no votes, no stuff classes and no class evidence, so the
class-aware steps (:mod:`dcseg.assign.adoption`, :mod:`dcseg.assign.instances`) have nothing
to work with and every HDBSCAN cluster used to be an object: a wall came out as dozens of
pieces and objects as two or three (demo scene: 186 instances for 19 objects, instance F1
0.42). Here clusters merge on the rule same-class clusters merge on in a classed run, less its
class checks: they touch (``AssignConfig.min_contacts`` contacts within the contact radius)
and the cosine of their unit feature centres is at least ``AssignConfig.merge_min_cosine``.
Groups smaller than ``AssignConfig.min_instance_gaussians`` are left out, as in classed runs.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.cluster.hierarchy import DisjointSet

from dcseg.assign.adoption import cluster_contacts
from dcseg.assign.config import AssignConfig
from dcseg.assign.instances import Instances, number_groups


def agnostic_instances(
    means: NDArray[np.float64],
    cluster_labels: NDArray[np.int64],
    centers: NDArray[np.floating[Any]],
    radius: float,
    cfg: AssignConfig,
) -> Instances:
    """Object instances of a class-agnostic run (module docstring); classes are all -1.

    Args:
        means: ``[N, 3]`` Gaussian centres.
        cluster_labels: ``[N]`` cluster per Gaussian, -1 = noise.
        centers: ``[K, D]`` unit feature centres of the clusters.
        radius: contact radius (world units, :func:`dcseg.cluster.outliers.adaptive_radius`).
        cfg: ``min_contacts``, ``neighbours``, ``merge_min_cosine``, ``min_instance_gaussians``.
    """
    labels = np.asarray(cluster_labels, dtype=np.int64)
    k = int(centers.shape[0])
    roots = merged_clusters(means, labels, centers, radius, cfg)
    group = np.where(labels >= 0, roots[np.maximum(labels, 0)], -1) if k else labels.copy()
    one_class = np.zeros(len(labels), dtype=np.int64)  # numbering only; classes are -1
    numbered = number_groups(
        group, one_class, np.zeros(len(labels)), labels, k, cfg.min_instance_gaussians
    )
    m = numbered.n_instances
    return Instances(numbered.ids, np.full(m, -1, np.int64), numbered.scores, numbered.of_cluster)


def merged_clusters(
    means: NDArray[np.float64],
    labels: NDArray[np.int64],
    centers: NDArray[np.floating[Any]],
    radius: float,
    cfg: AssignConfig,
) -> NDArray[np.int64]:
    """``[K]`` root cluster of each cluster after merging touching clusters whose feature
    centres agree (union-find over the qualifying pairs)."""
    k = int(centers.shape[0])
    sets = DisjointSet(range(k))
    if radius > 0 and k > 1:
        pairs, counts = cluster_contacts(means, labels, radius, cfg.neighbours)
        pairs = pairs[counts >= cfg.min_contacts]
        unit = np.asarray(centers, dtype=np.float64)
        unit = unit / np.maximum(np.linalg.norm(unit, axis=1, keepdims=True), 1e-12)
        cosine = np.einsum("ij,ij->i", unit[pairs[:, 0]], unit[pairs[:, 1]])
        for a, b in pairs[cosine >= cfg.merge_min_cosine]:
            sets.merge(int(a), int(b))
    return np.array([sets[i] for i in range(k)], dtype=np.int64)
