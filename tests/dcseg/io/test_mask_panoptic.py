"""Panoptic PNG + segments_info (COCO panoptic, detectron2 pairs): one source, both readers."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from dcseg.errors import InputError
from dcseg.io.folders import FrameSelection
from dcseg.io.mask_formats import COCO_PANOPTIC, PANOPTIC_PAIRS, detect_masks
from dcseg.io.masks import decode_masks, read_agnostic_masks
from dcseg.io.semantic import read_semantic_maps
from dcseg.types import Vocabulary
from tests.dcseg.io.mask_files import write_json, write_panoptic_png

VOCABULARY = Vocabulary(("wall", "floor", "chair", "table"))
COCO_CATEGORIES = [
    {"id": 7, "name": "chair", "isthing": 1},
    {"id": 40, "name": "wall", "isthing": 0},
    {"id": 41, "name": "floor", "isthing": 0},
]
# Ids above 255 use the G and B channels: 70000 = (112, 17, 1).
WALL, FLOOR, CHAIR_A, CHAIR_B = 300, 70000, 5, 6


def panoptic_ids() -> np.ndarray:
    ids = np.zeros((6, 8), dtype=np.int64)
    ids[:2] = WALL
    ids[4:] = FLOOR
    ids[2:4, 1:3] = CHAIR_A
    ids[2:4, 5:7] = CHAIR_B
    return ids


def coco_segments() -> list[dict[str, int]]:
    return [
        {"id": WALL, "category_id": 40, "isthing": 0, "iscrowd": 0},
        {"id": FLOOR, "category_id": 41, "isthing": 0, "iscrowd": 0},
        {"id": CHAIR_A, "category_id": 7, "isthing": 1, "iscrowd": 0},
        {"id": CHAIR_B, "category_id": 7, "isthing": 1, "iscrowd": 0},
    ]


def write_coco_panoptic(folder: Path, stems: tuple[str, ...] = ("000", "001")) -> Path:
    """COCO panoptic: panoptic.json with annotations + categories, PNGs in panoptic/."""
    annotations = []
    for i, stem in enumerate(stems):
        write_panoptic_png(folder / "panoptic" / f"{stem}.png", panoptic_ids())
        annotations.append(
            {"image_id": i, "file_name": f"{stem}.png", "segments_info": coco_segments()}
        )
    data = {"annotations": annotations, "categories": COCO_CATEGORIES, "images": []}
    return write_json(folder / "panoptic.json", data)


def expected_classes() -> np.ndarray:
    ids = panoptic_ids()
    classes = np.full(ids.shape, -1, dtype=np.int32)
    classes[ids == WALL] = 0
    classes[ids == FLOOR] = 1
    classes[(ids == CHAIR_A) | (ids == CHAIR_B)] = 2
    return classes


def test_coco_panoptic_feeds_both_readers(tmp_path: Path) -> None:
    folder = tmp_path / "masks"
    write_coco_panoptic(folder)
    assert detect_masks(folder).kind == COCO_PANOPTIC
    masks = read_agnostic_masks(folder)
    assert sorted(masks) == ["000", "001"]
    dense = decode_masks(masks["000"])
    ids = panoptic_ids()
    for mask, segment in zip(dense, (WALL, FLOOR, CHAIR_A, CHAIR_B), strict=True):
        np.testing.assert_array_equal(mask, ids == segment)
    assert masks["000"].source == "masks/panoptic/000.png"
    maps = read_semantic_maps(folder, VOCABULARY)
    np.testing.assert_array_equal(maps["001"].classes, expected_classes())


def test_coco_panoptic_json_given_as_a_file(tmp_path: Path) -> None:
    index = write_coco_panoptic(tmp_path / "masks")
    assert len(read_agnostic_masks(index)["000"]) == 4
    np.testing.assert_array_equal(
        read_semantic_maps(index, VOCABULARY)["000"].classes, expected_classes()
    )


def test_detectron2_pairs_category_id_is_the_vocabulary_index(tmp_path: Path) -> None:
    folder = tmp_path / "pan"
    write_panoptic_png(folder / "f0.png", panoptic_ids())
    segments = [
        {"id": WALL, "category_id": 0, "isthing": False},
        {"id": FLOOR, "category_id": 1, "isthing": False},
        {"id": CHAIR_A, "category_id": 2, "isthing": True},
        {"id": CHAIR_B, "category_id": 2, "isthing": True},
    ]
    write_json(folder / "f0.json", segments)
    write_panoptic_png(folder / "f1.png", panoptic_ids())
    write_json(folder / "f1.json", {"segments_info": segments})
    assert detect_masks(folder).kind == PANOPTIC_PAIRS
    assert [len(m) for m in read_agnostic_masks(folder).values()] == [4, 4]
    maps = read_semantic_maps(folder, VOCABULARY)
    for stem in ("f0", "f1"):
        np.testing.assert_array_equal(maps[stem].classes, expected_classes())


def test_size_and_frame_selection(tmp_path: Path) -> None:
    write_coco_panoptic(tmp_path / "m", ("000", "001", "002"))
    selection = FrameSelection(frozenset({"001"}), frozenset({"000", "001", "002"}))
    masks = read_agnostic_masks(tmp_path / "m", size=(16, 12), frames=selection)
    assert list(masks) == ["001"]
    assert (masks["001"].width, masks["001"].height) == (16, 12)
    maps = read_semantic_maps(tmp_path / "m", VOCABULARY, size=(4, 3), frames=selection)
    assert maps["001"].classes.shape == (3, 4)


def test_error_panoptic_id_missing_from_segments_info(tmp_path: Path) -> None:
    folder = tmp_path / "pan"
    write_panoptic_png(folder / "f0.png", panoptic_ids())
    write_json(
        folder / "f0.json", [{"id": WALL, "category_id": 0}, {"id": FLOOR, "category_id": 1}]
    )
    for read in (
        lambda: read_agnostic_masks(folder),
        lambda: read_semantic_maps(folder, VOCABULARY),
    ):
        with pytest.raises(InputError) as info:
            read()
        (problem,) = info.value.problems
        assert problem.path == "pan/f0.png"
        assert problem.reason == (
            "panoptic id 5 (RGB 5,0,0), 6 (RGB 6,0,0) not in the segments_info of pan/f0.json"
        )


def test_error_segments_info_fields_named(tmp_path: Path) -> None:
    folder = tmp_path / "m"
    index = write_coco_panoptic(folder)
    data = {
        "annotations": [
            {
                "file_name": "000.png",
                "segments_info": [{"id": WALL}, {"id": "x", "category_id": 1}],
            },
            {"file_name": "001.png", "segments_info": coco_segments()},
            {"file_name": "nope.png", "segments_info": []},
        ],
        "categories": COCO_CATEGORIES,
    }
    write_json(index, data)
    with pytest.raises(InputError) as info:
        read_agnostic_masks(folder)
    reasons = [str(p) for p in info.value.problems]
    assert reasons == [
        "m/panoptic.json: annotations[2]: nope.png not found in m/panoptic or m or m/Annotations",
        "m/panoptic.json: segments_info of 000.png[0].category_id must be a non-negative "
        "integer, got None",
        "m/panoptic.json: segments_info of 000.png[1].id must be a non-negative integer, got 'x'",
    ]


def test_error_category_not_in_vocabulary(tmp_path: Path) -> None:
    write_coco_panoptic(tmp_path / "m", ("000",))
    with pytest.raises(InputError) as info:
        read_semantic_maps(tmp_path / "m", Vocabulary(("wall", "floor")))
    assert [str(p) for p in info.value.problems] == [
        "m/panoptic.json: segment 5: category 'chair' is not in the vocabulary",
        "m/panoptic.json: segment 6: category 'chair' is not in the vocabulary",
    ]


def test_error_category_id_beyond_vocabulary_without_categories(tmp_path: Path) -> None:
    folder = tmp_path / "pan"
    write_panoptic_png(folder / "f0.png", np.full((2, 2), 9))
    write_json(folder / "f0.json", [{"id": 9, "category_id": 4}])
    with pytest.raises(InputError, match=r"pan/f0.json: segment 9: category_id 4 is beyond"):
        read_semantic_maps(folder, VOCABULARY)


def test_error_pair_halves_missing(tmp_path: Path) -> None:
    folder = tmp_path / "pan"
    write_panoptic_png(folder / "a.png", panoptic_ids())
    write_json(folder / "a.json", coco_segments())
    write_panoptic_png(folder / "b.png", panoptic_ids())
    write_json(folder / "c.json", coco_segments())
    with pytest.raises(InputError) as info:
        read_agnostic_masks(folder)
    assert [str(p) for p in info.value.problems] == [
        "pan/b.png: panoptic PNG without its b.json",
        "pan/c.json: segments_info without its c.png",
    ]


def test_sam_json_beside_a_label_png_is_not_a_pair(tmp_path: Path) -> None:
    """A SAM record list has 'segmentation': the stem in two formats stays a per-frame error."""
    write_json(tmp_path / "m" / "a.json", [{"segmentation": {"size": [1, 1], "counts": "01"}}])
    write_panoptic_png(tmp_path / "m" / "a.png", np.ones((1, 1)))
    with pytest.raises(InputError, match="several formats"):
        read_agnostic_masks(tmp_path / "m")


def test_deva_style_palette_ids_jpg_names_and_scores(tmp_path: Path) -> None:
    """DEVA: palette PNG of segment ids, pred.json naming the frame's image, segment scores."""
    from dcseg.io.mask_formats.scores import MinScores
    from tests.dcseg.io.mask_files import write_palette_png

    ids = np.zeros((6, 8), dtype=np.uint8)
    ids[:3] = 1
    ids[3:, :4] = 2
    ids[3:, 4:] = 3
    write_palette_png(tmp_path / "deva" / "Annotations" / "00000.png", ids)
    segments = [
        {"id": 1, "category_id": 0, "score": 0.9},
        {"id": 2, "category_id": 2, "score": 0.4},
        {"id": 3, "category_id": 3, "score": 0.8},
    ]
    annotations = [{"file_name": "00000.jpg", "segments_info": segments}]
    categories = [{"id": i, "name": n} for i, n in enumerate(VOCABULARY.names)]
    data = {"annotations": annotations, "categories": categories}
    write_json(tmp_path / "deva" / "pred.json", data)
    masks = read_agnostic_masks(tmp_path / "deva")["00000"]
    np.testing.assert_array_equal(decode_masks(masks), [ids == 1, ids == 2, ids == 3])
    kept = read_agnostic_masks(tmp_path / "deva", min_scores=MinScores(score=0.5))["00000"]
    np.testing.assert_array_equal(decode_masks(kept), [ids == 1, ids == 3])
    classes = read_semantic_maps(tmp_path / "deva", VOCABULARY)["00000"].classes
    np.testing.assert_array_equal(classes, np.choose(ids, [-1, 0, 2, 3]))


def test_error_bad_segment_score(tmp_path: Path) -> None:
    folder = tmp_path / "pan"
    write_panoptic_png(folder / "f0.png", np.full((2, 2), 9))
    write_json(folder / "f0.json", [{"id": 9, "category_id": 1, "score": "high"}])
    with pytest.raises(InputError, match=r"pan/f0.json: segments_info\[0\]: 'score' must be a"):
        read_agnostic_masks(folder)
