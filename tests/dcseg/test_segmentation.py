"""A segmentation's counts, its per-view object maps and the labels evaluation reads."""

from __future__ import annotations

import math

import numpy as np

from dcseg.assign.instances import Instances
from dcseg.assign.stage import Assignment
from dcseg.cluster.features import Clustering
from dcseg.segmentation import Labels, Segmentation


def segmentation() -> Segmentation:
    """Gaussians 0-5 in three clusters (0, 0, 1, 1, 2, noise); clusters 0 and 1 are one object
    (class 4), cluster 2 is in none."""
    clustering = Clustering(
        np.array([0, 0, 1, 1, 2, -1]), np.eye(3, dtype=np.float32), np.ones(6, np.float32)
    )
    assignment = Assignment(np.array([4, 4, -1]), np.ones(3), np.zeros((3, 5)), np.ones(3, int))
    instances = Instances(
        np.array([0, 0, 0, 0, -1, -1]), np.array([4]), np.array([1.0]), np.array([0, 0, -1])
    )
    semantic = np.array([4, 4, 4, 4, -1, -1])
    clusters = {"v0": np.array([[0, 1, 2, -1]], np.int32)}
    labels = {"v0": np.array([[4, 4, -1, -1]], np.int32)}
    return Segmentation(clustering, assignment, instances, semantic, clusters, labels)


def test_counts_are_the_clusters_and_the_objects() -> None:
    seg = segmentation()
    assert seg.n_clusters == 3 and seg.n_instances == 1
    assert math.isnan(seg.mask_agreement) and not seg.evidence_trusted


def test_instance_map_reads_each_clusters_object_through_the_cluster_map() -> None:
    """Clusters 0 and 1 show object 0; cluster 2 (in no object) and empty pixels show -1."""
    instance = segmentation().instance_map("v0")
    assert instance.dtype == np.int64 and instance.tolist() == [[0, 0, -1, -1]]


def test_labels_are_what_evaluation_needs() -> None:
    seg = segmentation()
    labels = seg.labels()
    assert isinstance(labels, Labels)
    assert labels.semantic_ids is seg.semantic_ids and labels.label_maps is seg.label_maps
