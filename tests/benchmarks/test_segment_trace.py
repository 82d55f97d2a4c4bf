"""segment_trace: which Gaussians stand for an object, what its clusters lie on and voted."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from benchmarks.segment_trace import cluster_line, makeup, object_gaussians, top
from dcseg.assign.stage import Assignment

NAMES = ("floor", "block", "domino")


def test_object_gaussians_are_the_nearest_opaque_ones_within_reach() -> None:
    """Gaussian 0 is nearest to point 0 but transparent, so point 0 takes Gaussian 1;
    point 1 is 10 cm from everything (beyond 5 cm) and takes none."""
    means = np.array([[0.0, 0, 0], [0.01, 0, 0], [0.02, 0, 0], [1.0, 0, 0]])
    opacities = np.array([0.01, 0.9, 0.9, 0.9])
    points = np.array([[0.0, 0, 0], [0.5, 0, 0], [0.021, 0, 0]])
    assert object_gaussians(means, opacities, points).tolist() == [1, 2]
    assert object_gaussians(means, np.zeros(4), points).tolist() == []


def test_makeup_counts_objects_under_the_centres_most_first() -> None:
    points = np.array([[0.0, 0, 0], [1.0, 0, 0]])
    instances = np.array([1, 17])
    centres = np.array([[0.0, 0, 0.01], [1.0, 0, 0], [1.0, 0.01, 0], [5.0, 0, 0]])
    assert makeup(instances, cKDTree(points), centres) == [(17, 2), (1, 1)]
    assert makeup(instances, cKDTree(points), np.zeros((0, 3))) == []


def test_top_names_the_largest_positive_values() -> None:
    assert top(np.array([0.5, 2.0, 0.0]), NAMES) == "block 2.00, floor 0.50"


def test_cluster_line_gives_size_vote_evidence_and_objects() -> None:
    votes = np.array([[0.0, 0.54, 0.59]])
    vote = Assignment(np.array([2]), np.array([0.52]), votes, np.array([9]))
    line = cluster_line(0, 5, 19, vote, np.array([0.0, 177.5, 116.1]), [(18, 19)], NAMES)
    assert line == (
        "cluster 0: 5 of the object's / 19; voted domino in 9 views (domino 0.59, block 0.54)"
        " | evidence of the object's part: block 177.50, domino 116.10 | lies on objects 18: 19"
    )
