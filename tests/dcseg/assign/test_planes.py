"""Plane geometry of stuff surfaces: coplanar clusters, and a region split into its planes."""

from __future__ import annotations

import numpy as np
import pytest

from dcseg.assign.config import AssignConfig
from dcseg.assign.planes import (
    PLANE_NEIGHBOURS,
    cluster_planes,
    coplanar,
    plane_labels,
    split_stuff_planes,
)
from tests.dcseg.assign.surfaces import DUCK, N_CLASSES, RADIUS, STUFF, WALL, corner, patch


def test_plane_labels_group_normals_up_to_sign() -> None:
    normals = np.array([[0, 0, 1], [0, 0, -1], [0.1, 0, 0.995], [1, 0, 0], [-1, 0, 0], [0, 1, 0]])
    labels = plane_labels(normals.astype(np.float64), 0.8, 2)
    assert labels[0] == labels[1] == labels[2] >= 0
    assert labels[3] == labels[4] >= 0 and labels[3] != labels[0]
    assert labels[5] == -1  # a direction with fewer than 2 normals


def test_cluster_planes_give_each_cluster_its_centroid_and_normal() -> None:
    """A floor patch (z = 0) is cluster 0, a wall patch (y = 0) cluster 2; cluster 1 is
    empty and its centroid zero."""
    floor = patch(0, 0.3, 0, 0.3)
    flat = patch(0, 0.3, 0, 0.2)
    wall = np.stack([flat[:, 0], np.zeros(len(flat)), flat[:, 1]], axis=1)
    means = np.concatenate([floor, wall])
    labels = np.repeat([0, 2], [len(floor), len(wall)])
    centroids, normals = cluster_planes(means, labels, 3)
    assert np.allclose(centroids[0], floor.mean(axis=0))
    assert np.allclose(centroids[2], wall.mean(axis=0))
    assert np.allclose(centroids[1], 0.0)
    assert abs(normals[0] @ [0, 0, 1]) == pytest.approx(1.0)
    assert abs(normals[2] @ [0, 1, 0]) == pytest.approx(1.0)
    assert np.allclose(np.linalg.norm(normals, axis=1), 1.0)


def test_clusters_are_coplanar_only_on_one_plane() -> None:
    """Next to a floor patch (cluster 0): more floor (1) is coplanar; a raised platform (2,
    parallel but 20 cm up) and a wall (3) are not; with the tests off, every pair is."""
    floor, more = patch(0, 0.3, 0, 0.3), patch(0.3, 0.6, 0, 0.3)
    raised = patch(0.3, 0.6, 0, 0.3, z=0.2)
    flat = patch(0, 0.3, 0, 0.3)
    wall = np.stack([flat[:, 0], np.full(len(flat), 0.3), flat[:, 1]], axis=1)
    parts = [floor, more, raised, wall]
    labels = np.repeat(np.arange(4), [len(p) for p in parts])
    planes = cluster_planes(np.concatenate(parts), labels, 4)
    a, b = np.zeros(3, dtype=np.int64), np.array([1, 2, 3])
    assert coplanar(*planes, a, b, AssignConfig()).tolist() == [True, False, False]
    off = AssignConfig(surface_min_normal_cosine=0.0, surface_max_tilt=1.0)
    assert coplanar(*planes, a, b, off).tolist() == [True, True, True]


def test_a_stuff_region_round_a_corner_splits_into_its_two_walls() -> None:
    """One region (key 5) of a stuff class that wraps round a corner becomes two regions, one
    per wall: the first keeps its key, the second takes the next free one (6). The same region
    of a thing class, or with too few Gaussians for a local normal, stays whole."""
    points = corner()
    half = len(points) // 2
    group = np.full(len(points), 5, dtype=np.int64)
    semantic = np.full(len(points), WALL, dtype=np.int64)
    stuff = np.zeros(N_CLASSES, dtype=bool)
    stuff[list(STUFF)] = True
    split = split_stuff_planes(points, group, semantic, stuff, RADIUS, AssignConfig())
    first, second = np.bincount(split[:half]).argmax(), np.bincount(split[half:]).argmax()
    assert set(split.tolist()) == {5, 6} and first != second
    assert np.mean(split[:half] == first) > 0.95 and np.mean(split[half:] == second) > 0.95
    things = np.full(len(points), DUCK, dtype=np.int64)
    assert split_stuff_planes(points, group, things, stuff, RADIUS, AssignConfig()).tolist() == (
        group.tolist()
    )
    few = slice(0, PLANE_NEIGHBOURS)
    kept = split_stuff_planes(points[few], group[few], semantic[few], stuff, RADIUS, AssignConfig())
    assert kept.tolist() == [5] * PLANE_NEIGHBOURS
