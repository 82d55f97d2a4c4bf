"""label_loss: every ground-truth point falls in the stage that lost its label."""

from __future__ import annotations

import numpy as np

from benchmarks.label_loss import majority, point_kinds
from dcseg.types import GroundTruth


def test_each_point_gets_the_stage_that_lost_it() -> None:
    """Points 0-1 belong to object 1 (class 0), 2-5 to object 2 (class 1); a Gaussian sits on
    every point but point 4 (1 m away). Point 0 is right; 1 sits on a noise Gaussian; 2 on
    object 1's Gaussian (transfer); 3 on a cluster most of whose Gaussians are object 1's
    (merged); 5 on its own object's cluster voted the wrong class (assignment)."""
    points = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0], [9, 9, 9], [5, 0, 0]], float)
    gt = GroundTruth(points, np.array([0, 0, 1, 1, 1, 1]), np.array([1, 1, 2, 2, 2, 2]))
    means = points[[0, 1, 2, 3, 5]]
    owner = np.array([1, 1, 1, 2, 2])
    labels = np.array([0, 1, 0, 0, 0])
    clusters = np.array([0, -1, 0, 1, 2])
    cluster_owner = np.array([1, 1, 2])
    kinds = point_kinds(gt, means, owner, labels, clusters, cluster_owner)
    assert kinds.tolist() == ["correct", "noise", "transfer", "merged", "none", "assignment"]


def test_majority_names_each_clusters_main_object() -> None:
    clusters = np.array([0, 0, 0, 1, 1, -1])
    owner = np.array([3, 3, 5, -1, 4, 3])
    assert majority(clusters, owner, 3).tolist() == [3, 4, -1]
