"""Object instances from clusters: merge fragments, adopt unlabelled ones, split stuff surfaces."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from numpy.typing import NDArray

from dcseg.assign.config import AssignConfig
from dcseg.assign.instances import (
    Instances,
    adopt_fragments,
    adopt_unlabelled,
    cluster_contacts,
    drop_fragments,
    object_instances,
    plane_labels,
)

SPACING = 0.02
RADIUS = 3 * SPACING
WALL, FLOOR, DUCK, MUG = 0, 1, 2, 3
N_CLASSES = 4
STUFF = (WALL, FLOOR)


def patch(x0: float, x1: float, y0: float, y1: float, z: float = 0.0) -> NDArray[np.float64]:
    """A flat grid of Gaussian centres at ``SPACING`` (a surface)."""
    xs = np.arange(x0, x1, SPACING)
    ys = np.arange(y0, y1, SPACING)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    return np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, z)], axis=1)


def unit(*values: float) -> NDArray[np.float32]:
    v = np.array(values, dtype=np.float32)
    return v / np.linalg.norm(v)


def build(
    parts: list[tuple[NDArray[np.float64], int]],
    classes: list[int],
    centers: list[NDArray[np.float32]],
    cfg: AssignConfig | None = None,
) -> tuple[Instances, NDArray[np.int64], NDArray[np.int64]]:
    """Objects of clusters ``parts[k] = (points, cluster)`` with cluster classes ``classes``.

    Votes: one view per cluster for its class (unlabelled clusters: none); no class evidence.
    Returns the instances, the Gaussians' clusters and their final classes.
    """
    cfg = cfg or AssignConfig()
    means = np.concatenate([p for p, _ in parts])
    labels = np.concatenate([np.full(len(p), k, dtype=np.int64) for p, k in parts])
    table = np.asarray(classes, dtype=np.int64)
    semantic = np.where(labels >= 0, table[np.maximum(labels, 0)], -1)
    votes = np.zeros((len(classes), N_CLASSES))
    for k, c in enumerate(classes):
        if c >= 0:
            votes[k, c] = 1.0
    evidence = np.zeros((len(means), N_CLASSES))
    fragments = adopt_fragments(means, labels, semantic, evidence, RADIUS, cfg)
    scores = (table >= 0).astype(np.float64)
    instances = object_instances(
        means, labels, fragments.semantic, fragments, np.stack(centers), votes, scores,
        STUFF, RADIUS, cfg,
    )  # fmt: skip
    return instances, labels, fragments.semantic


def test_two_fragments_of_one_object_merge() -> None:
    """Two touching duck clusters with similar features are one object; with merging off
    (threshold above any cosine) they stay two."""
    left, right = patch(0, 0.3, 0, 0.3), patch(0.3, 0.6, 0, 0.3)
    parts = [(left, 0), (right, 1)]
    centers = [unit(1, 0.2, 0), unit(1, 0, 0.2)]
    merged, labels, _ = build(parts, [DUCK, DUCK], centers)
    assert merged.n_instances == 1
    assert np.all(merged.ids == 0) and merged.classes.tolist() == [DUCK]
    assert merged.of_cluster.tolist() == [0, 0]
    off = AssignConfig(merge_min_cosine=1.0, merge_near=False)
    apart, _, _ = build(parts, [DUCK, DUCK], centers, off)
    assert apart.n_instances == 2


def test_near_pieces_with_agreeing_features_are_one_object() -> None:
    """Two duck pieces 5 cm apart (within the contact radius, no contacts among the 4 nearest
    neighbours): one object with ``merge_near``, two without it, with unlike features or when
    farther apart than the radius."""
    left = patch(0, 0.3, 0, 0.3)
    near, far = patch(0.33, 0.63, 0, 0.3), patch(0.38, 0.68, 0, 0.3)
    labels = np.repeat([0, 1], [len(left), len(near)])
    assert len(cluster_contacts(np.concatenate([left, near]), labels, RADIUS, 4)[0]) == 0
    alike, unlike = [unit(1, 0.3, 0), unit(1, 0, 0.3)], [unit(1, 0, 0), unit(-0.2, 1, 0)]
    on = AssignConfig(neighbours=4, merge_near=True, near_min_cosine=0.3)
    assert build([(left, 0), (near, 1)], [DUCK, DUCK], alike, on)[0].n_instances == 1
    off = replace(on, merge_near=False)
    assert build([(left, 0), (near, 1)], [DUCK, DUCK], alike, off)[0].n_instances == 2
    assert build([(left, 0), (near, 1)], [DUCK, DUCK], unlike, on)[0].n_instances == 2
    assert build([(left, 0), (far, 1)], [DUCK, DUCK], alike, on)[0].n_instances == 2
    assert build([(left, 0), (near, 1)], [DUCK, MUG], alike, on)[0].n_instances == 2


def test_touching_objects_of_different_class_or_features_stay_apart() -> None:
    left, right = patch(0, 0.3, 0, 0.3), patch(0.3, 0.6, 0, 0.3)
    same = [unit(1, 0, 0), unit(1, 0, 0)]
    by_class, _, _ = build([(left, 0), (right, 1)], [DUCK, MUG], same)
    assert by_class.n_instances == 2 and sorted(by_class.classes.tolist()) == [DUCK, MUG]
    # two mugs side by side: same class, touching, but their features differ
    by_features, _, _ = build([(left, 0), (right, 1)], [MUG, MUG], [unit(1, 0, 0), unit(0, 1, 0)])
    assert by_features.n_instances == 2


def test_far_fragments_of_one_class_do_not_merge() -> None:
    near, far = patch(0, 0.3, 0, 0.3), patch(2, 2.3, 0, 0.3)
    result, _, _ = build([(near, 0), (far, 1)], [DUCK, DUCK], [unit(1, 0, 0)] * 2)
    assert result.n_instances == 2


def test_an_unlabelled_fragment_joins_its_neighbour_and_a_lonely_one_is_dropped() -> None:
    body, head, lonely = patch(0, 0.3, 0, 0.3), patch(0.3, 0.4, 0, 0.3), patch(3, 3.3, 0, 0.3)
    parts = [(body, 0), (head, 1), (lonely, 2)]
    centers = [unit(1, 0, 0), unit(0, 1, 0), unit(0, 0, 1)]  # features unlike: adoption ignores
    result, labels, semantic = build(parts, [DUCK, -1, -1], centers)
    assert result.n_instances == 1 and result.classes.tolist() == [DUCK]
    assert np.all(result.ids[labels <= 1] == 0)
    assert np.all(semantic[labels == 1] == DUCK)
    assert np.all(result.ids[labels == 2] == -1) and np.all(semantic[labels == 2] == -1)
    assert result.of_cluster.tolist() == [0, 0, -1]


def test_stuff_is_one_region_per_connected_surface() -> None:
    """Two floor clusters apart are two regions; a wall cut into three touching clusters with
    unlike features is one (stuff ignores features)."""
    floor_a, floor_b = patch(0, 0.5, 0, 0.5), patch(1.5, 2.0, 0, 0.5)
    wall = [patch(x, x + 0.3, 2, 2.3) for x in (0.0, 0.3, 0.6)]
    parts = [(floor_a, 0), (floor_b, 1), (wall[0], 2), (wall[1], 3), (wall[2], 4)]
    centers = [unit(1, 0, 0), unit(0, 1, 0), unit(0, 0, 1), unit(1, 1, 0), unit(1, 0, 1)]
    result, labels, _ = build(parts, [FLOOR, FLOOR, WALL, WALL, WALL], centers)
    assert sorted(result.classes.tolist()) == [WALL, FLOOR, FLOOR]
    assert result.of_cluster[0] != result.of_cluster[1]
    assert len(set(result.of_cluster[2:].tolist())) == 1
    assert len(set(result.ids[labels >= 2].tolist())) == 1
    unlike = [unit(1, 0, 0), unit(0, 1, 0), unit(0, 0, 1), unit(-1, 0.2, 0), unit(0.1, -1, 0.1)]
    things, _, _ = build(parts, [DUCK, DUCK, MUG, MUG, MUG], unlike)
    assert things.n_instances == 5, "objects with unlike features do not merge"


def test_small_instances_are_left_out() -> None:
    crumb = patch(0, 0.06, 0, 0.06)  # 9 Gaussians
    result, _, semantic = build([(crumb, 0)], [DUCK], [unit(1, 0, 0)])
    assert result.n_instances == 0 and np.all(result.ids == -1)
    assert np.all(semantic == DUCK)
    kept, _, _ = build(
        [(crumb, 0)], [DUCK], [unit(1, 0, 0)], AssignConfig(min_instance_gaussians=5)
    )
    assert kept.n_instances == 1


def test_contacts_count_each_gaussian_once_per_other_cluster() -> None:
    means = np.array([[0, 0, 0], [0.01, 0, 0], [0.02, 0, 0], [5, 0, 0]], dtype=np.float64)
    labels = np.array([0, 1, 1, 2])
    pairs, counts = cluster_contacts(means, labels, 0.015, 3)
    assert pairs.tolist() == [[0, 1]] and counts.tolist() == [2]  # Gaussian 0 and Gaussian 1


def test_thresholds_are_validated() -> None:
    with pytest.raises(ValueError, match="merge_min_cosine"):
        AssignConfig(merge_min_cosine=2.0)
    with pytest.raises(ValueError, match="contact_factor"):
        replace(AssignConfig(), contact_factor=0.0)
    with pytest.raises(ValueError, match="near_min_cosine"):
        AssignConfig(near_min_cosine=1.5)
    with pytest.raises(ValueError, match="min_instance_gaussians"):
        AssignConfig(min_instance_gaussians=-1)


def test_walls_meeting_at_a_corner_are_two_surfaces() -> None:
    """Two touching wall clusters at a right angle are two regions (their planes differ);
    with the surface tests off they are one."""
    flat = patch(0, 0.6, 0, 0.6)
    wall_x = np.stack([flat[:, 0], np.zeros(len(flat)), flat[:, 1]], axis=1)  # y = 0 plane
    wall_y = np.stack([np.zeros(len(flat)), flat[:, 0] + SPACING, flat[:, 1]], axis=1)  # x = 0
    parts = [(wall_x, 0), (wall_y, 1)]
    centers = [unit(1, 0, 0)] * 2
    split, _, _ = build(parts, [WALL, WALL], centers)
    assert split.n_instances == 2 and split.classes.tolist() == [WALL, WALL]
    off = AssignConfig(surface_min_normal_cosine=0.0, surface_max_tilt=1.0)
    one, _, _ = build(parts, [WALL, WALL], centers, off)
    assert one.n_instances == 1


def test_a_raised_platform_is_not_the_floor() -> None:
    """Parallel but offset: the step between the centroids leaves the planes."""
    low, high = patch(0, 0.5, 0, 0.5), patch(0.5, 1.0, 0, 0.5, z=0.2)
    bridge = patch(0.48, 0.52, 0, 0.5, z=0.1)  # they touch through a few Gaussians
    parts = [(low, 0), (np.concatenate([high, bridge]), 1)]
    result, labels, _ = build(parts, [FLOOR, FLOOR], [unit(1, 0, 0)] * 2)
    low_ids, high_ids = set(result.ids[: len(low)]), set(result.ids[len(low) : -len(bridge)])
    assert len(low_ids) == len(high_ids) == 1 and low_ids != high_ids and -1 not in low_ids
    # the bridge lies 10 cm from both planes: the plane split leaves it a region of its own
    assert set(result.ids[-len(bridge) :]).isdisjoint(low_ids | high_ids)


def _corner(noise: float = 0.0) -> NDArray[np.float64]:
    """One wall along y = 0 and one along x = 0, meeting at the z axis, as one point set."""
    flat = patch(0, 0.8, 0, 0.6)
    wall_x = np.stack([flat[:, 0] + SPACING, np.zeros(len(flat)), flat[:, 1]], axis=1)
    wall_y = np.stack([np.zeros(len(flat)), flat[:, 0] + SPACING, flat[:, 1]], axis=1)
    points = np.concatenate([wall_x, wall_y])
    return points + np.random.default_rng(0).normal(0.0, noise, points.shape)


def test_one_cluster_round_a_corner_is_two_walls() -> None:
    """A single wall cluster that wraps round a corner: the coplanar test never sees two
    clusters, the plane split gives two regions, one per wall; off, it stays one."""
    points = _corner()
    half = len(points) // 2
    split, _, _ = build([(points, 0)], [WALL], [unit(1, 0, 0)])
    assert split.n_instances == 2
    first, second = np.bincount(split.ids[:half]).argmax(), np.bincount(split.ids[half:]).argmax()
    assert first != second
    assert np.mean(split.ids[:half] == first) > 0.95  # corner Gaussians may go either way
    assert np.mean(split.ids[half:] == second) > 0.95
    whole, _, _ = build(
        [(points, 0)], [WALL], [unit(1, 0, 0)], AssignConfig(split_stuff_planes=False)
    )
    assert whole.n_instances == 1


def test_a_noisy_floor_stays_one_region_and_objects_are_never_split() -> None:
    floor = patch(0, 1.2, 0, 1.2)
    floor[:, 2] += np.random.default_rng(1).normal(0.0, 0.004, len(floor))
    result, _, _ = build([(floor, 0)], [FLOOR], [unit(1, 0, 0)])
    assert result.n_instances == 1
    duck, _, _ = build([(_corner(), 0)], [DUCK], [unit(1, 0, 0)])
    assert duck.n_instances == 1


def test_plane_labels_group_normals_up_to_sign() -> None:
    normals = np.array([[0, 0, 1], [0, 0, -1], [0.1, 0, 0.995], [1, 0, 0], [-1, 0, 0], [0, 1, 0]])
    labels = plane_labels(normals.astype(np.float64), 0.8, 2)
    assert labels[0] == labels[1] == labels[2] >= 0
    assert labels[3] == labels[4] >= 0 and labels[3] != labels[0]
    assert labels[5] == -1  # a direction with fewer than 2 normals


def test_a_loose_patch_far_smaller_than_the_objects_of_its_class_dissolves() -> None:
    """A 25-Gaussian duck patch next to a 225-Gaussian duck is a fragment (below 15 % of the
    largest duck): it leaves the instance list, keeping its class. A lone 25-Gaussian mug is
    the only mug and stays; a small floor region is stuff and stays."""
    duck, patch_, mug = patch(0, 0.3, 0, 0.3), patch(1, 1.1, 0, 0.1), patch(3, 3.1, 0, 0.1)
    floor, floor_bit = patch(0, 1, 2, 3), patch(5, 5.1, 2, 2.1)
    parts = [(duck, 0), (patch_, 1), (mug, 2), (floor, 3), (floor_bit, 4)]
    centers = [unit(1, 0, 0), unit(0, 1, 0), unit(0, 0, 1), unit(1, 1, 0), unit(1, 0, 1)]
    classes = [DUCK, DUCK, MUG, FLOOR, FLOOR]
    cfg = AssignConfig(min_fragment_share=0.15)
    result, labels, semantic = build(parts, classes, centers, cfg)
    assert sorted(result.classes.tolist()) == sorted([DUCK, MUG, FLOOR, FLOOR])
    assert np.all(result.ids[labels == 1] == -1) and np.all(semantic[labels == 1] == DUCK)
    assert result.of_cluster[1] == -1 and result.of_cluster[2] >= 0
    kept, _, _ = build(parts, classes, centers, AssignConfig(min_fragment_share=0.0))
    assert kept.n_instances == 5


def test_drop_fragments_keeps_every_object_when_off_or_alone() -> None:
    group = np.array([0] * 100 + [1] * 5 + [-1] * 3, dtype=np.int64)
    semantic = np.array([DUCK] * 105 + [-1] * 3, dtype=np.int64)
    stuff = np.zeros(N_CLASSES, dtype=bool)
    out = drop_fragments(group, semantic, stuff, 0.1)
    assert out.tolist() == [0] * 100 + [-1] * 8
    assert drop_fragments(group, semantic, stuff, 0.0).tolist() == group.tolist()
    stuff[DUCK] = True
    assert drop_fragments(group, semantic, stuff, 0.1).tolist() == group.tolist()


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


def test_gaussians_whose_class_changed_leave_their_instance() -> None:
    objects = Instances(
        np.array([0, 0, 1, 1, -1]), np.array([3, 4]), np.array([0.9, 0.8]), np.array([0, 1])
    )
    moved = objects.of_classes(np.array([3, 4, 4, 4, 2]))
    assert moved.ids.tolist() == [0, -1, 1, 1, -1]
    assert moved.classes.tolist() == [3, 4] and moved.n_instances == 2
    none = Instances(np.full(3, -1), np.zeros(0, np.int64), np.zeros(0), np.zeros(0, np.int64))
    assert none.of_classes(np.array([0, 1, 2])).ids.tolist() == [-1, -1, -1]
    with pytest.raises(ValueError, match="labels"):
        objects.of_classes(np.array([3, 4]))
