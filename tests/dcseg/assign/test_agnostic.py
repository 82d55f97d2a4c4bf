"""Objects of a class-agnostic run: touching clusters with agreeing features merge."""

from __future__ import annotations

import numpy as np

from dcseg.assign.agnostic import agnostic_instances
from dcseg.assign.config import AssignConfig
from dcseg.assign.objects import build_objects
from dcseg.assign.stage import Assignment
from dcseg.cluster.features import Clustering
from tests.dcseg.assign.surfaces import RADIUS, patch

LEFT, RIGHT = patch(0, 0.3, 0, 0.3), patch(0.3, 0.6, 0, 0.3)  # touching along x = 0.3
FAR = patch(2.0, 2.3, 0, 0.3)
MEANS = np.concatenate([LEFT, RIGHT, FAR])
LABELS = np.repeat([0, 1, 2], [len(LEFT), len(RIGHT), len(FAR)])
CFG = AssignConfig(merge_min_cosine=0.5)


def centers(right: list[float]) -> np.ndarray:
    return np.array([[1.0, 0.0], right, [1.0, 0.0]], np.float32)


def test_touching_clusters_with_agreeing_features_are_one_object() -> None:
    instances = agnostic_instances(MEANS, LABELS, centers([0.8, 0.6]), RADIUS, CFG)
    assert instances.n_instances == 2  # left+right, and the far one (same features, apart)
    assert len(set(instances.ids[LABELS < 2].tolist())) == 1
    assert instances.ids[LABELS == 2][0] != instances.ids[0]
    assert instances.classes.tolist() == [-1, -1]
    assert instances.of_cluster.tolist() == [0, 0, 1]


def test_touching_clusters_with_different_features_stay_apart() -> None:
    instances = agnostic_instances(MEANS, LABELS, centers([0.0, 1.0]), RADIUS, CFG)
    assert instances.n_instances == 3


def test_small_groups_are_left_out() -> None:
    speck = patch(2.0, 2.06, 0, 0.06)  # 9 Gaussians, below min_instance_gaussians (20)
    means = np.concatenate([LEFT, RIGHT, speck])
    labels = np.repeat([0, 1, 2], [len(LEFT), len(RIGHT), len(speck)])
    instances = agnostic_instances(means, labels, centers([0.0, 1.0]), RADIUS, CFG)
    assert instances.n_instances == 2 and (instances.ids[labels == 2] == -1).all()
    assert instances.of_cluster.tolist() == [0, 1, -1]


def test_build_objects_merges_without_classes_and_keeps_clusters_with_objects_off() -> None:
    clustering = Clustering(LABELS.copy(), centers([0.8, 0.6]), np.ones(len(LABELS), np.float32))
    none = Assignment(np.full(3, -1), np.zeros(3), np.zeros((3, 0)), np.zeros(3, np.int64))
    semantic = np.full(len(LABELS), -1)
    merged, ids = build_objects(MEANS, RADIUS, None, clustering, none, semantic, CFG, ())
    assert merged.n_instances == 2 and (ids == -1).all()
    off = AssignConfig(objects=False)
    per_cluster, _ = build_objects(MEANS, RADIUS, None, clustering, none, semantic, off, ())
    assert per_cluster.n_instances == 3
