"""Unlabelled clusters adopt the class of the labelled clusters they touch."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from dcseg.assign.adoption import adopt_fragments, adopt_unlabelled, cluster_contacts
from dcseg.assign.config import AssignConfig
from tests.dcseg.assign.surfaces import DUCK, FLOOR, N_CLASSES, RADIUS, patch


def test_contacts_count_each_gaussian_once_per_other_cluster() -> None:
    means = np.array([[0, 0, 0], [0.01, 0, 0], [0.02, 0, 0], [5, 0, 0]], dtype=np.float64)
    labels = np.array([0, 1, 1, 2])
    pairs, counts = cluster_contacts(means, labels, 0.015, 3)
    assert pairs.tolist() == [[0, 1]] and counts.tolist() == [2]  # Gaussian 0 and Gaussian 1


@pytest.mark.parametrize(("weight", "adopted", "parent"), [(1.0, DUCK, 0), (10.0, FLOOR, -1)])
def test_an_unlabelled_cluster_weighs_its_own_evidence_against_its_neighbours(
    weight: float, adopted: int, parent: int
) -> None:
    """Cluster 1 touches only cluster 0 (a duck, 6 contacts); its own pooled evidence is
    floor 0.8 / duck 0.2. As completion does, it takes the class that maximises neighbour
    share + weight x own share, a class no neighbour has included: with weight 1 the duck
    (1 + 0.2 against 0.8) and it joins cluster 0; with weight 10 (trusted evidence) floor
    (8 against 3), joining no one."""
    classes = np.array([DUCK, -1])
    pairs, counts = np.array([[0, 1]]), np.array([6])
    pooled = np.array([[0.0, 0.0, 5.0, 0.0], [0.0, 4.0, 1.0, 0.0]])
    cfg = replace(AssignConfig(), evidence_weight=weight)
    out, parents = adopt_unlabelled(classes, pairs, counts, pooled, cfg)
    assert out.tolist() == [DUCK, adopted]
    assert parents.tolist() == [-1, parent]


def test_a_chain_of_unlabelled_clusters_is_adopted_pass_by_pass() -> None:
    """Cluster 0 (floor) touches 1, 1 touches 2, 2 touches 3; cluster 4 touches nobody. 1
    adopts floor in the first pass, 2 in the second (joining 1), 3 in the third; 4 stays
    unlabelled. 3's own duck evidence (weight 1: duck 1.0 against floor 1.0 + 0.0) ties with
    its floor neighbour, and a tie goes to the lower class id (floor)."""
    classes = np.array([FLOOR, -1, -1, -1, -1])
    pairs, counts = np.array([[0, 1], [1, 2], [2, 3]]), np.array([6, 6, 6])
    pooled = np.zeros((5, N_CLASSES))
    pooled[:3, FLOOR] = 1.0
    pooled[3, DUCK] = 1.0
    out, parents = adopt_unlabelled(classes, pairs, counts, pooled, AssignConfig())
    assert out.tolist() == [FLOOR, FLOOR, FLOOR, FLOOR, -1]
    assert parents.tolist()[:3] == [-1, 0, 1] and parents[4] == -1
    few = np.array([6, 6, 4])  # 2-3 under min_contacts: 3 is never reached
    out, _ = adopt_unlabelled(classes, pairs, few, pooled, AssignConfig())
    assert out.tolist() == [FLOOR, FLOOR, FLOOR, -1, -1]


def test_adopt_fragments_fills_in_the_classes_of_adopted_clusters() -> None:
    """A duck body (cluster 0) touches an unlabelled head (1); a lonely patch (2) and a noise
    Gaussian touch nobody. The head adopts the duck class and joins the body, its Gaussians
    take the class; the lonely patch and the noise Gaussian keep none."""
    body, head, lonely = patch(0, 0.3, 0, 0.3), patch(0.3, 0.4, 0, 0.3), patch(3, 3.3, 0, 0.3)
    noise = np.array([[6.0, 0.0, 0.0]])
    means = np.concatenate([body, head, lonely, noise])
    labels = np.repeat([0, 1, 2, -1], [len(body), len(head), len(lonely), 1])
    semantic = np.where(labels == 0, DUCK, -1)
    evidence = np.zeros((len(means), N_CLASSES))
    fragments = adopt_fragments(means, labels, semantic, evidence, RADIUS, AssignConfig())
    assert fragments.classes.tolist() == [DUCK, DUCK, -1]
    assert fragments.parent.tolist() == [-1, 0, -1]
    assert fragments.pairs.tolist() == [[0, 1]] and fragments.counts[0] >= 5
    assert fragments.semantic.tolist() == np.where(np.isin(labels, [0, 1]), DUCK, -1).tolist()
    assert semantic[labels == 1].tolist() == [-1] * len(head)  # the input is not changed
