"""The realistic level's segmenter failures: each deterministic by seed, its property asserted."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from dcseg.synth.catalogue import VOCABULARY
from dcseg.synth.failures import (
    LOOKALIKES,
    REALISTIC_VOCABULARY,
    InstanceFates,
    coarse,
    draw_fates,
    fill_unlabelled,
    realistic_agnostic,
    realistic_classes,
    realistic_semantic,
    sam_instance_map,
    touching_pairs,
)
from dcseg.synth.generate import perturbed_pose
from dcseg.synth.noise import NOISE_LEVELS, Failures, NoiseLevel
from dcseg.synth.scene import SceneInstance

FLOOR, TABLE, MUG, LEGO, DUCK, TEDDY = 1, 2, 3, 4, 5, 6
VOCAB = REALISTIC_VOCABULARY.index


def _inst(i: int, name: str, kind: str, support: int) -> SceneInstance:
    return SceneInstance(i, name, kind, "mesh", (0.0, 0.0, 0.0), 0.0, support, -1)


INSTANCES = {
    FLOOR: _inst(FLOOR, "floor", "structure", 0),
    TABLE: _inst(TABLE, "table", "furniture", FLOOR),
    MUG: _inst(MUG, "mug", "object", TABLE),
    LEGO: _inst(LEGO, "lego", "object", TABLE),
    DUCK: _inst(DUCK, "duck", "object", FLOOR),
    TEDDY: _inst(TEDDY, "teddy", "object", FLOOR),
}


def room() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A 40x48 view: floor, a table with a mug and a small lego, a duck touching a teddy."""
    ids = np.full((40, 48), FLOOR, dtype=np.int32)
    ids[0:20, 0:24] = TABLE
    ids[4:14, 4:14] = MUG
    ids[16:18, 18:20] = LEGO  # 4 px: small
    ids[24:36, 4:16] = DUCK
    ids[24:36, 16:28] = TEDDY  # shares an edge with the duck
    classes = np.vectorize(lambda i: VOCAB(INSTANCES[i].class_name))(ids).astype(np.int32)
    rows, cols = np.mgrid[0:40, 0:48]
    xyz = np.stack([cols * 0.01, rows * 0.01, np.zeros_like(rows, dtype=np.float64)], axis=-1)
    return ids, classes, xyz


def test_realistic_vocabulary_keeps_indices_and_has_lookalikes() -> None:
    assert REALISTIC_VOCABULARY[: len(VOCABULARY)] == VOCABULARY
    assert len(set(REALISTIC_VOCABULARY)) == len(REALISTIC_VOCABULARY) > len(VOCABULARY)
    for name, choices in LOOKALIKES.items():
        assert name in VOCABULARY and all(c in REALISTIC_VOCABULARY for c in choices)


def test_fates_are_drawn_once_per_scene_and_deterministic() -> None:
    sure = Failures(lookalike_prob=1.0, rare_miss_prob=1.0)
    fates = draw_fates(INSTANCES, sure, np.random.default_rng(0))
    assert fates.missed == {LEGO}
    assert set(fates.lookalike) == {TABLE, MUG, DUCK, TEDDY}
    for inst_id, index in fates.lookalike.items():
        assert REALISTIC_VOCABULARY[index] in LOOKALIKES[INSTANCES[inst_id].class_name]
    again = draw_fates(INSTANCES, sure, np.random.default_rng(0))
    assert again == fates
    never = draw_fates(INSTANCES, Failures(0.0, rare_miss_prob=0.0), np.random.default_rng(0))
    assert never == InstanceFates()


def test_lookalike_repeats_in_most_views_and_missed_rare_object_in_every_view() -> None:
    ids, classes, _ = room()
    fates = InstanceFates({MUG: VOCAB("cup")}, frozenset({LEGO}))
    failures = Failures(lookalike_view_prob=0.8, swallow_fraction=0.0)
    rng = np.random.default_rng(1)
    views = [realistic_classes(ids, classes, INSTANCES, fates, failures, rng) for _ in range(60)]
    cup_share = np.mean([v[ids == MUG][0] == VOCAB("cup") for v in views])
    assert 0.65 < cup_share < 0.95  # most views, not all
    assert all(np.all(v[ids == LEGO] == VOCAB("table")) for v in views)  # its support
    assert all(np.all(v[ids == DUCK] == VOCAB("duck")) for v in views)


def test_small_objects_take_their_supports_class() -> None:
    ids, classes, _ = room()
    failures = Failures(swallow_fraction=10 / ids.size)  # below 10 px: the 4-px lego
    out = realistic_classes(
        ids, classes, INSTANCES, InstanceFates(), failures, np.random.default_rng(0)
    )
    assert np.all(out[ids == LEGO] == VOCAB("table"))
    assert np.all(out[ids == MUG] == VOCAB("mug"))
    off = realistic_classes(
        ids,
        classes,
        INSTANCES,
        InstanceFates(),
        Failures(swallow_fraction=0.0),
        np.random.default_rng(0),
    )
    assert np.all(off[ids == LEGO] == VOCAB("lego"))


def test_coarse_maps_are_blocky_and_keep_the_size() -> None:
    labels = np.arange(42 * 50).reshape(42, 50)
    out = coarse(labels, 4)
    assert out.shape == labels.shape
    blocks = out[:40, :48].reshape(10, 4, 12, 4)
    assert np.all(blocks == blocks[:, :1, :, :1])  # every 4x4 block holds one label
    assert np.array_equal(coarse(labels, 1), labels)
    assert len(np.unique(out)) < len(np.unique(labels)) // 10


def test_maps_never_abstain() -> None:
    classes = np.full((10, 12), -1, dtype=np.int32)
    classes[:, :4], classes[:, 8:] = 2, 5
    filled = fill_unlabelled(classes)
    assert filled.min() >= 0
    assert np.all(filled[:, :5] == 2) and np.all(filled[:, 7:] == 5)
    ids, gt, _ = room()
    gt[0:3, 0:3] = -1
    level = replace(NOISE_LEVELS["realistic"], hole_rate=3.0)  # holes, then filled
    failures = Failures()
    out = realistic_semantic(
        ids, gt, INSTANCES, InstanceFates(), level, failures, np.random.default_rng(2)
    )
    assert out.min() >= 0 and out.shape == gt.shape


def test_sam_view_uncovers_a_share_of_objects_and_merges_touching_ones() -> None:
    ids, _, _ = room()
    assert touching_pairs(ids, INSTANCES) == [(DUCK, TEDDY)]  # objects only, not the table
    merge = Failures(merge_prob=1.0, uncovered=(0.0, 0.0))
    seen = sam_instance_map(ids, INSTANCES, merge, np.random.default_rng(0))
    assert np.all(seen[ids == TEDDY] == DUCK) and np.all(seen[ids == MUG] == MUG)
    hide = Failures(merge_prob=0.0, uncovered=(0.25, 0.25))  # 1 of the 4 objects
    for seed in range(5):
        seen = sam_instance_map(ids, INSTANCES, hide, np.random.default_rng(seed))
        hidden = [i for i in (MUG, LEGO, DUCK, TEDDY) if np.all(seen[ids == i] == -1)]
        assert len(hidden) == 1 and np.all(seen[ids == TABLE] == TABLE)
    a = sam_instance_map(ids, INSTANCES, Failures(), np.random.default_rng(3))
    assert np.array_equal(a, sam_instance_map(ids, INSTANCES, Failures(), np.random.default_rng(3)))


def test_sam_masks_are_coarse_merged_and_nested() -> None:
    ids, _, xyz = room()
    level = NoiseLevel(part_prob=1.0, group_prob=1.0)
    failures = Failures(merge_prob=1.0, uncovered=(0.0, 0.0), mask_factor=2)
    normals = {i: np.array([1.0, 0.0, 0.0]) for i in INSTANCES}
    masks = realistic_agnostic(
        ids, xyz, INSTANCES, normals, level, failures, np.random.default_rng(0)
    )
    assert masks.shape[1:] == ids.shape
    blocks = masks.reshape(len(masks), 20, 2, 24, 2)
    assert np.all(blocks == blocks[:, :, :1, :, :1])  # computed at half resolution
    duck, teddy = ids == DUCK, ids == TEDDY
    assert any(np.array_equal(m, duck | teddy) for m in masks)  # one object-level mask
    assert not any(np.array_equal(m, duck) or np.array_equal(m, teddy) for m in masks)
    mug = ids == MUG
    whole = [m for m in masks if np.array_equal(m, mug)]
    parts = [m for m in masks if m.any() and np.all(m <= mug) and m.sum() < mug.sum()]
    groups = [m for m in masks if np.all(m >= mug) and m[ids == TABLE].any()]
    assert whole and len(parts) >= 2 and groups  # part < object < group
    again = realistic_agnostic(
        ids, xyz, INSTANCES, normals, level, failures, np.random.default_rng(0)
    )
    assert np.array_equal(masks, again)


def test_pose_error_moves_the_written_pose_only_as_asked() -> None:
    c2w = np.eye(4)
    c2w[:3, 3] = [1.0, 2.0, 3.0]
    assert np.array_equal(perturbed_pose(c2w, 0.0, 0.0, np.random.default_rng(0)), c2w)
    angles, shifts = [], []
    for seed in range(200):
        out = perturbed_pose(c2w, 1.0, 0.0, np.random.default_rng(seed))
        assert np.allclose(out[:3, :3] @ out[:3, :3].T, np.eye(3)) and np.allclose(
            out[:3, 3], c2w[:3, 3]
        )
        angles.append(np.degrees(np.arccos(np.clip((np.trace(out[:3, :3]) - 1) / 2, -1, 1))))
        shifts.append(
            perturbed_pose(c2w, 0.0, 0.02, np.random.default_rng(seed))[:3, 3] - c2w[:3, 3]
        )
    assert 0.6 < np.sqrt(np.mean(np.square(angles))) < 1.4  # N(0, 1 deg) angle
    assert 0.015 < np.std(shifts) < 0.025
    assert np.array_equal(
        perturbed_pose(c2w, 1.0, 0.02, np.random.default_rng(7)),
        perturbed_pose(c2w, 1.0, 0.02, np.random.default_rng(7)),
    )


def test_failures_validation() -> None:
    with pytest.raises(ValueError, match="merge_prob must be in"):
        Failures(merge_prob=1.5)
    with pytest.raises(ValueError, match="uncovered must be a range"):
        Failures(uncovered=(0.3, 0.1))
    with pytest.raises(ValueError, match="class_factor and mask_factor"):
        Failures(class_factor=0)


pybullet = pytest.importorskip("pybullet")


def test_realistic_scene_and_cli_options(tmp_path: Path) -> None:
    from dcseg.cli import main
    from dcseg.synth import SynthConfig, generate_scene
    from dcseg.synth.generate import true_poses

    scene = generate_scene(SynthConfig(seed=1, noise="realistic", frames=3, width=80, height=60))
    assert scene.vocabulary.names == REALISTIC_VOCABULARY
    assert all(m.classes.min() >= 0 for m in scene.semantic)  # never abstains
    again = generate_scene(SynthConfig(seed=1, noise="realistic", frames=3, width=80, height=60))
    for a, b in zip(scene.semantic, again.semantic, strict=True):
        assert np.array_equal(a.classes, b.classes)
    assert [m.rles for m in scene.agnostic] == [m.rles for m in again.agnostic]
    moved = generate_scene(
        SynthConfig(seed=1, noise="realistic", pose_error_deg=1.0, frames=3, width=80, height=60)
    )
    for f, g in zip(scene.capture.frames, moved.capture.frames, strict=True):
        assert np.array_equal(f.rgb, g.rgb) and not np.allclose(f.c2w, g.c2w)
    truth = true_poses(
        SynthConfig(seed=1, noise="realistic", pose_error_deg=1.0, frames=3, width=80, height=60)
    )
    np.testing.assert_array_equal(np.stack([f.c2w for f in scene.capture.frames]), truth)
    out = tmp_path / "scene"
    args = ["synth", str(out), "--frames", "2", "--size", "64x48", "--noise", "realistic"]
    args += ["--depth-sigma", "0.01", "--pose-error-deg", "0.5", "--pose-error-m", "0.01"]
    assert main(args) == 0
    summary = json.loads((out / "scene.json").read_text())
    assert summary["noise_level"]["depth_sigma"] == 0.01
    assert summary["noise_level"]["failures"]["class_factor"] == 4
    assert summary["pose_error"] == {"deg": 0.5, "m": 0.01}
    assert (out / "vocabulary.txt").read_text().splitlines() == list(REALISTIC_VOCABULARY)
    assert main(["synth", str(tmp_path / "bad"), "--pose-error-deg", "20"]) == 2
