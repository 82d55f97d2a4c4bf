"""Object instances from clusters: merge fragments, adopt unlabelled ones, split stuff surfaces.

Each test builds objects end to end (adoption, merging, plane split, dissolving).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from numpy.typing import NDArray

from dcseg.assign.adoption import adopt_fragments, cluster_contacts
from dcseg.assign.config import AssignConfig
from dcseg.assign.instances import Instances, drop_fragments, object_instances
from tests.dcseg.assign.surfaces import (
    DUCK,
    FLOOR,
    MUG,
    N_CLASSES,
    RADIUS,
    SPACING,
    STUFF,
    WALL,
    corner,
    patch,
    unit,
)


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


def test_one_cluster_round_a_corner_is_two_walls() -> None:
    """A single wall cluster that wraps round a corner: the coplanar test never sees two
    clusters, the plane split gives two regions, one per wall; off, it stays one."""
    points = corner()
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
    duck, _, _ = build([(corner(), 0)], [DUCK], [unit(1, 0, 0)])
    assert duck.n_instances == 1


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
