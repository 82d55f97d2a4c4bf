"""From labelled clusters to objects: adoption, completion, instances, own evidence.

The scene: a duck body (cluster 0, labelled), its head (cluster 1, unlabelled, touching the
body) and one noise Gaussian beside the body, without a class.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from numpy.typing import NDArray

from dcseg.assign.config import AssignConfig
from dcseg.assign.objects import build_objects, per_cluster_instances, stuff_ids
from dcseg.assign.stage import Assignment
from dcseg.cluster.features import Clustering
from tests.dcseg.assign.surfaces import DUCK, MUG, N_CLASSES, RADIUS, SPACING, patch

BODY, HEAD = patch(0, 0.3, 0, 0.3), patch(0.3, 0.4, 0, 0.3)
NOISE = np.array([[0.1, -SPACING, 0.0]])
MEANS = np.concatenate([BODY, HEAD, NOISE])
LABELS = np.repeat([0, 1, -1], [len(BODY), len(HEAD), 1])
SEMANTIC = np.where(LABELS == 0, DUCK, -1)
CFG = AssignConfig(objects=True, complete=False, follow_evidence_ratio=0.0)


def scene() -> tuple[Clustering, Assignment]:
    centers = np.array([[1.0, 0.0], [0.0, 1.0]], np.float32)
    clustering = Clustering(LABELS.copy(), centers, np.ones(len(LABELS), np.float32))
    votes = np.zeros((2, N_CLASSES))
    votes[0, DUCK] = 2.0
    assignment = Assignment(np.array([DUCK, -1]), np.array([1.0, 0.0]), votes, np.array([2, 0]))
    return clustering, assignment


def build(cfg: AssignConfig, evidence: NDArray[np.float64] | None = None, radius: float = RADIUS):
    ev = np.zeros((len(MEANS), N_CLASSES)) if evidence is None else evidence
    clustering, assignment = scene()
    return build_objects(MEANS, radius, ev, clustering, assignment, SEMANTIC.copy(), cfg, ())


def test_stuff_ids_are_the_vocabularys_stuff_classes() -> None:
    assert stuff_ids(["wall", "duck", "floor"], ("floor", "wall", "ceiling")) == [0, 2]
    assert stuff_ids(["duck", "mug"], ("floor", "wall")) == []


def test_per_cluster_instances_are_the_clusters() -> None:
    _, assignment = scene()
    instances = per_cluster_instances(LABELS, assignment)
    assert instances.ids.tolist() == LABELS.tolist()
    assert instances.classes.tolist() == [DUCK, -1] and instances.scores.tolist() == [1.0, 0.0]
    assert instances.of_cluster.tolist() == [0, 1]


def test_the_unlabelled_head_joins_the_body_as_one_object() -> None:
    instances, ids = build(CFG)
    assert instances.n_instances == 1 and instances.classes.tolist() == [DUCK]
    assert ids[LABELS >= 0].tolist() == [DUCK] * (len(BODY) + len(HEAD))
    assert ids[-1] == -1  # no completion: the noise Gaussian keeps no class
    assert (instances.ids[LABELS >= 0] == 0).all() and instances.of_cluster.tolist() == [0, 0]


def test_completion_alone_labels_gaussians_and_keeps_one_instance_per_cluster() -> None:
    instances, ids = build(replace(CFG, objects=False, complete=True))
    assert ids[-1] == DUCK  # beside the body: completed
    assert instances.ids.tolist() == LABELS.tolist() and instances.classes.tolist() == [DUCK, -1]
    both, both_ids = build(replace(CFG, complete=True))
    assert both_ids[-1] == DUCK and both.n_instances == 1


@pytest.mark.parametrize(
    ("cfg", "radius", "evidence"),
    [
        (replace(CFG, objects=False, complete=False), RADIUS, True),
        (CFG, 0.0, True),
        (CFG, RADIUS, False),
    ],
    ids=["off", "no-radius", "no-evidence"],
)
def test_without_objects_completion_radius_or_evidence_clusters_are_the_instances(
    cfg: AssignConfig, radius: float, evidence: bool
) -> None:
    clustering, assignment = scene()
    ev = np.zeros((len(MEANS), N_CLASSES)) if evidence else None
    instances, ids = build_objects(MEANS, radius, ev, clustering, assignment, SEMANTIC, cfg, ())
    assert ids is SEMANTIC
    assert instances.ids.tolist() == LABELS.tolist() and instances.of_cluster.tolist() == [0, 1]


def test_gaussians_following_their_own_evidence_leave_their_object() -> None:
    """Ten body Gaussians whose own evidence says mug: with ``follow_evidence_ratio`` they
    take the mug class and leave the duck; off, they stay."""
    evidence = np.zeros((len(MEANS), N_CLASSES))
    evidence[: len(BODY), DUCK] = 1.0
    evidence[:10] = 0.0
    evidence[:10, MUG] = 1.0
    moved, ids = build(replace(CFG, follow_evidence_ratio=0.5), evidence)
    assert ids[:10].tolist() == [MUG] * 10 and (moved.ids[:10] == -1).all()
    assert (ids[10 : len(BODY)] == DUCK).all() and (moved.ids[10 : len(BODY)] == 0).all()
    stayed, ids = build(CFG, evidence)
    assert ids[:10].tolist() == [DUCK] * 10 and (stayed.ids[:10] == 0).all()
