"""The segmenter-error generators: each deterministic by seed, the errors it claims present."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from dcseg.synth.errors import (
    ERROR_MODELS,
    ErrorModel,
    SceneTruth,
    ViewOutput,
    ViewTruth,
    error_model,
)
from dcseg.synth.errors.detector import (
    Detection,
    DetectorFates,
    DetectorModel,
    DetectorParams,
    box_prompted_mask,
    draw_detections,
    similar_classes,
)
from dcseg.synth.errors.lowres import (
    CONFUSION,
    LowResFates,
    LowResModel,
    LowResParams,
    block_majority,
    confused_class,
    draw_lowres,
)
from dcseg.synth.failures import LOOKALIKES, REALISTIC_VOCABULARY
from dcseg.synth.scene import SceneInstance

FLOOR, WALL, TABLE, MUG, LEGO, DUCK, TEDDY = 1, 2, 3, 4, 5, 6, 7
VOCAB = REALISTIC_VOCABULARY.index


def _inst(i: int, name: str, kind: str, support: int) -> SceneInstance:
    return SceneInstance(i, name, kind, "mesh", (0.0, 0.0, 0.0), 0.0, support, -1)


INSTANCES = {
    FLOOR: _inst(FLOOR, "floor", "structure", 0),
    WALL: _inst(WALL, "wall", "structure", 0),
    TABLE: _inst(TABLE, "table", "furniture", FLOOR),
    MUG: _inst(MUG, "mug", "object", TABLE),
    LEGO: _inst(LEGO, "lego", "object", TABLE),
    DUCK: _inst(DUCK, "duck", "object", FLOOR),
    TEDDY: _inst(TEDDY, "teddy", "object", FLOOR),
}
EXTENTS = {FLOOR: 5.0, WALL: 5.0, TABLE: 1.3, MUG: 0.15, LEGO: 0.06, DUCK: 0.2, TEDDY: 0.35}
SCENE = SceneTruth(INSTANCES, {i: np.array([1.0, 0.0, 0.0]) for i in INSTANCES}, EXTENTS)


def room() -> ViewTruth:
    """An 80x96 view: a wall over the floor, a table holding a mug and a 16-px lego, a duck
    touching a teddy at the same depth (2.0 m), the mug 5 cm in front of the table top."""
    ids = np.full((80, 96), FLOOR, dtype=np.int32)
    ids[:16] = WALL
    depth = np.full(ids.shape, 3.0, dtype=np.float32)
    ids[20:44, 8:56], depth[20:44, 8:56] = TABLE, 2.5
    ids[24:36, 12:28], depth[24:36, 12:28] = MUG, 2.45
    ids[36:40, 40:44] = LEGO
    ids[52:72, 8:32], depth[52:72, 8:32] = DUCK, 2.0
    ids[52:72, 32:56], depth[52:72, 32:56] = TEDDY, 2.0
    classes = np.vectorize(lambda i: VOCAB(INSTANCES[i].class_name))(ids).astype(np.int32)
    rows, cols = np.mgrid[0:80, 0:96]
    xyz = np.stack([cols * 0.01, rows * 0.01, depth.astype(np.float64)], axis=-1)
    return ViewTruth(ids, classes, xyz, depth)


def _views(model: ErrorModel, fates: object, n: int, seed: int = 0) -> list[ViewOutput]:
    truth = room()
    return [
        model.view(
            truth,
            SCENE,
            fates,
            np.random.default_rng([seed, 1, i]),
            np.random.default_rng([seed, 2, i]),
        )
        for i in range(n)
    ]


def _majority(classes: np.ndarray, pixels: np.ndarray) -> int:
    values, counts = np.unique(classes[pixels], return_counts=True)
    return int(values[counts.argmax()])


def test_registry_names_match_the_cli_and_refuse_unknown_names() -> None:
    from dcseg.cli.synth import ERROR_MODEL_CHOICES

    assert tuple(ERROR_MODELS) == ERROR_MODEL_CHOICES
    assert {error_model(name).name for name in ERROR_MODELS} == set(ERROR_MODELS)
    with pytest.raises(ValueError, match="error_model must be one of"):
        error_model("sam3")


# --- detector ----------------------------------------------------------------------------


def test_detector_fates_are_deterministic_and_confuse_by_appearance_or_size() -> None:
    sure = DetectorParams(confuse_prob=1.0, small_miss_prob=1.0)
    fates = draw_detections(SCENE, sure, np.random.default_rng(0))
    assert fates == draw_detections(SCENE, sure, np.random.default_rng(0))
    assert fates.missed == {LEGO}  # the only object below small_extent
    assert set(fates.detections) == {TABLE, MUG, DUCK, TEDDY}  # never walls or the floor
    for inst_id, found in fates.detections.items():
        name = INSTANCES[inst_id].class_name
        assert found.confused and REALISTIC_VOCABULARY[found.label] != name
        assert REALISTIC_VOCABULARY[found.label] in similar_classes(name, EXTENTS[inst_id], {})
    none = DetectorParams(0.0, small_miss_prob=0.0)
    never = draw_detections(SCENE, none, np.random.default_rng(0))
    assert not never.missed and not any(d.confused for d in never.detections.values())


def test_detector_similar_classes_are_lookalikes_and_same_size() -> None:
    sizes = {"mug": 0.15, "cup": 0.12, "ball": 0.3, "table": 1.3, "brick": 0.1, "wall": 0.15}
    found = similar_classes("mug", 0.15, sizes)
    assert set(LOOKALIKES["mug"]) <= set(found)
    assert "table" not in found and "wall" not in found and "mug" not in found


def test_detector_confused_object_keeps_its_wrong_class_in_most_views() -> None:
    fates = DetectorFates(
        {
            TABLE: Detection(VOCAB("table"), 0.9),
            MUG: Detection(VOCAB("cup"), 0.9, confused=True),
            DUCK: Detection(VOCAB("duck"), 0.9),
            TEDDY: Detection(VOCAB("teddy"), 0.9),
        },
        frozenset({LEGO}),
    )
    model = DetectorModel(DetectorParams(confuse_view_prob=0.9, score_noise=0.0))
    views = _views(model, fates, 40)
    mug, lego = room().instance_map == MUG, room().instance_map == LEGO
    share = np.mean([_majority(v.classes, mug) == VOCAB("cup") for v in views])
    assert 0.8 <= share < 1.0  # most views, not all
    for v in views:  # the missed lego: no class, no mask of its own, in every view
        assert np.all(v.classes[lego] != VOCAB("lego"))
        assert not any(np.array_equal(m, lego) for m in v.masks)
    a, b = _views(model, fates, 3, seed=5), _views(model, fates, 3, seed=5)
    assert all(np.array_equal(x.masks, y.masks) for x, y in zip(a, b, strict=True))


def test_detector_masks_are_coarse_dilated_and_bleed_into_neighbours_at_the_same_depth() -> None:
    truth = room()
    params = DetectorParams(dilate_px=1, box_margin=0.1)
    duck = box_prompted_mask(truth.instance_map, truth.depth, DUCK, params)
    own = truth.instance_map == DUCK
    assert np.all(duck[own])
    assert duck[truth.instance_map == TEDDY].any()  # the teddy touches it at 2.0 m
    assert not duck[truth.instance_map == FLOOR].any() or duck.sum() > own.sum()
    mug = box_prompted_mask(truth.instance_map, truth.depth, MUG, params)
    assert mug[truth.instance_map == TABLE].any()  # the table top 5 cm behind it
    none = DetectorParams(0.0, small_miss_prob=0.0)
    fates = draw_detections(SCENE, none, np.random.default_rng(1))
    out = _views(DetectorModel(DetectorParams(score_noise=0.0)), fates, 1)[0]
    blocks = out.masks.reshape(len(out.masks), 40, 2, 48, 2)
    assert np.all(blocks == blocks[:, :, :1, :, :1])  # computed at half resolution
    assert out.scores is not None and len(out.scores) == len(out.masks)
    assert all(0.0 <= s <= 1.0 for s in out.scores)


def test_detector_drops_low_scores_and_abstains_where_nothing_was_detected() -> None:
    fates = DetectorFates({MUG: Detection(VOCAB("mug"), 0.2), DUCK: Detection(VOCAB("duck"), 0.9)})
    out = _views(DetectorModel(DetectorParams(min_score=0.35, score_noise=0.0)), fates, 1)[0]
    ids = room().instance_map
    far_teddy = (ids == TEDDY) & (np.arange(96) >= 40)[None, :]  # beyond the duck's box
    assert np.all(out.classes[far_teddy] == -1)  # not detected: no class
    assert not np.any(out.classes[ids == MUG] == VOCAB("mug"))  # below min_score: dropped
    assert np.all(out.classes[ids == WALL] == VOCAB("wall"))  # from the wall prompt


# --- lowres ------------------------------------------------------------------------------


def test_lowres_confusion_matrix_rows_and_frequencies() -> None:
    for name, row in CONFUSION.items():
        assert name in REALISTIC_VOCABULARY and sum(p for _, p in row) < 1.0
        assert all(other in REALISTIC_VOCABULARY and other != name for other, _ in row)
    rng = np.random.default_rng(0)
    draws = [confused_class("mug", rng) for _ in range(4000)]
    for other, p in CONFUSION["mug"]:
        assert abs(draws.count(other) / 4000 - p) < 0.03
    assert {confused_class("wall", rng) for _ in range(50)} == {"wall"}


def test_lowres_fates_are_deterministic() -> None:
    fates = draw_lowres(SCENE, LowResParams(), np.random.default_rng(3))
    assert fates == draw_lowres(SCENE, LowResParams(), np.random.default_rng(3))
    assert set(fates.uncover) == {MUG, LEGO, DUCK, TEDDY}
    assert all(0.0 <= p <= 1.0 for p in fates.uncover.values())


def test_lowres_confused_instance_is_wrong_in_every_view_and_maps_are_blocky() -> None:
    labels = {i: VOCAB(inst.class_name) for i, inst in INSTANCES.items()}
    labels[DUCK] = VOCAB("bird")
    fates = LowResFates(labels, dict.fromkeys((MUG, LEGO, DUCK, TEDDY), 0.0), 7)
    views = _views(LowResModel(LowResParams(factor=8)), fates, 10)
    ids = room().instance_map
    assert all(_majority(v.classes, ids == DUCK) == VOCAB("bird") for v in views)
    for v in views:
        assert v.classes.min() >= 0  # never abstains
        blocks = v.classes.reshape(10, 8, 12, 8)
        assert np.all(blocks == blocks[:, :1, :, :1])  # 1/8 resolution
        assert not np.any(v.classes == VOCAB("lego"))  # 4x4 px: swallowed by the table
    assert np.array_equal(block_majority(np.array([[1, 1], [2, -1]]), 2), np.array([[1]]))


def test_lowres_sam_merges_same_depth_neighbours_and_leaves_objects_uncovered() -> None:
    truth = room()
    ids = truth.instance_map
    labels = {i: VOCAB(inst.class_name) for i, inst in INSTANCES.items()}
    merge = LowResParams(merge_prob=1.0, mask_factor=2, stuff_split_prob=0.0)
    fates = LowResFates(labels, dict.fromkeys((MUG, LEGO, DUCK, TEDDY), 0.0), 7)
    for out in _views(LowResModel(merge), fates, 3):
        both = (ids == DUCK) | (ids == TEDDY)
        assert any(np.array_equal(m, both) for m in out.masks)  # same depth: merged
        table = np.isin(ids, [TABLE, MUG, LEGO])  # the mug 5 cm off, the lego on it
        assert any(np.array_equal(m, table) for m in out.masks)
    near = LowResParams(merge_prob=1.0, merge_depth=0.03, mask_factor=2, stuff_split_prob=0.0)
    out = _views(LowResModel(near), fates, 1)[0]
    assert any(np.array_equal(m, ids == MUG) for m in out.masks)  # 5 cm > 3 cm: kept
    hide = LowResFates(labels, {MUG: 1.0, LEGO: 0.0, DUCK: 0.0, TEDDY: 0.0}, 7)
    for out in _views(LowResModel(merge), hide, 3):
        assert not any(m[ids == MUG].any() for m in out.masks)
    never = LowResParams(merge_prob=0.0, mask_factor=2, stuff_split_prob=0.0)
    out = _views(LowResModel(never), fates, 1)[0]
    assert any(np.array_equal(m, ids == DUCK) for m in out.masks)


# --- whole scenes ------------------------------------------------------------------------

pybullet = pytest.importorskip("pybullet")


@pytest.mark.parametrize("name", sorted(ERROR_MODELS))
def test_generator_scenes_are_deterministic_and_written(name: str, tmp_path: Path) -> None:
    from dcseg.synth import SynthConfig, generate_scene, write_scene

    cfg = SynthConfig(seed=2, frames=3, width=80, height=60, error_model=name)
    scene, again = generate_scene(cfg), generate_scene(cfg)
    assert scene.vocabulary.names == REALISTIC_VOCABULARY
    assert [m.rles for m in scene.agnostic] == [m.rles for m in again.agnostic]
    for a, b in zip(scene.semantic, again.semantic, strict=True):
        assert np.array_equal(a.classes, b.classes)
    write_scene(scene, tmp_path)
    assert json.loads((tmp_path / "scene.json").read_text())["error_model"] == name
    records = json.loads((tmp_path / "masks" / "agnostic" / "frame_0000.json").read_text())
    assert ("score" in records[0]) == (name == "detector")


def test_realistic_generator_equals_the_realistic_level_and_cli(tmp_path: Path) -> None:
    from dcseg.cli import main
    from dcseg.synth import SynthConfig, generate_scene

    level = generate_scene(SynthConfig(1, 3, 80, 60, noise="realistic"))
    model = generate_scene(SynthConfig(1, 3, 80, 60, noise="default", error_model="realistic"))
    assert [m.rles for m in level.agnostic] == [m.rles for m in model.agnostic]
    with pytest.raises(ValueError, match="error_model must be one of"):
        SynthConfig(error_model="sam3")
    out = tmp_path / "scene"
    args = ["synth", str(out), "--frames", "2", "--size", "64x48", "--error-model", "lowres"]
    assert main(args) == 0
    assert json.loads((out / "scene.json").read_text())["error_model"] == "lowres"
