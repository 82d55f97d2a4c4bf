"""One COCO instance JSON for all frames: polygons (pycocotools frPyObjects) and RLEs."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pycocotools.mask as mask_util
import pytest

from dcseg.errors import InputError
from dcseg.io.folders import FrameSelection
from dcseg.io.images import MAX_PIXELS
from dcseg.io.mask_formats import COCO_INSTANCES, detect_masks
from dcseg.io.mask_formats.rle import decode_rle
from dcseg.io.masks import decode_masks, read_agnostic_masks
from dcseg.io.semantic import read_semantic_maps
from dcseg.types import Vocabulary
from tests.dcseg.io.mask_files import write_json

SQUARE = [2.0, 1.0, 7.0, 1.0, 7.0, 5.0, 2.0, 5.0]
TRIANGLE: list[float] = [0, 0, 4, 0, 0, 4]


def reference(polygons: list[list[float]], height: int, width: int) -> np.ndarray:
    """The reference COCO API's rasterisation (what ``annToMask`` gives)."""
    merged = mask_util.merge(mask_util.frPyObjects(polygons, height, width))
    return decode_rle(merged)  # pycocotools' decode warns under numpy 2


def rle_of(mask: np.ndarray) -> dict[str, Any]:
    rle = mask_util.encode(np.asfortranarray(mask.astype(np.uint8)))
    return {"size": rle["size"], "counts": rle["counts"].decode()}


def coco(annotations: list[dict[str, Any]], n_images: int = 2) -> dict[str, Any]:
    images = [
        {"id": i + 1, "file_name": f"rgb/frame_{i:04d}.jpg", "height": 8, "width": 10}
        for i in range(n_images)
    ]
    categories = [{"id": 1, "name": "chair"}]
    return {"images": images, "annotations": annotations, "categories": categories}


def test_polygons_and_rles_one_mask_per_annotation(tmp_path: Path) -> None:
    crowd = np.zeros((8, 10), bool)
    crowd[6:, :] = True
    # uncompressed (iscrowd) counts, column-major: each of the 10 columns is 6 off then 2 on
    list_counts = {"size": [8, 10], "counts": [6, 2] * 10}
    annotations = [
        {"id": 10, "image_id": 1, "category_id": 1, "segmentation": [SQUARE]},
        {"id": 11, "image_id": 1, "category_id": 1, "segmentation": [SQUARE, TRIANGLE]},
        {"id": 12, "image_id": 1, "category_id": 1, "segmentation": rle_of(crowd), "iscrowd": 1},
        {"id": 13, "image_id": 1, "category_id": 1, "segmentation": list_counts, "iscrowd": 1},
        {"id": 14, "image_id": 2, "category_id": 1, "segmentation": TRIANGLE, "score": 0.4},
    ]
    write_json(tmp_path / "masks" / "instances.json", coco(annotations))
    assert detect_masks(tmp_path / "masks").kind == COCO_INSTANCES
    masks = read_agnostic_masks(tmp_path / "masks")
    assert sorted(masks) == ["frame_0000", "frame_0001"]
    dense = decode_masks(masks["frame_0000"])
    square = np.zeros((8, 10), bool)
    square[1:5, 2:7] = True  # x from 2 to 7, y from 1 to 5: the pixels whose centres are inside
    np.testing.assert_array_equal(dense[0], square)
    np.testing.assert_array_equal(dense[0], reference([SQUARE], 8, 10))
    np.testing.assert_array_equal(dense[1], reference([SQUARE, TRIANGLE], 8, 10))
    np.testing.assert_array_equal(dense[2], crowd)
    np.testing.assert_array_equal(dense[3], crowd)
    np.testing.assert_array_equal(
        decode_masks(masks["frame_0001"])[0], reference([list(map(float, TRIANGLE))], 8, 10)
    )
    assert masks["frame_0000"].source == "masks/instances.json"


def test_json_file_given_directly_with_size_and_frames(tmp_path: Path) -> None:
    annotations = [{"id": 1, "image_id": 2, "segmentation": [SQUARE]}]
    index = write_json(tmp_path / "instances.json", coco(annotations, n_images=3))
    selection = FrameSelection(frozenset({"frame_0001"}), None)
    masks = read_agnostic_masks(index, size=(20, 16), frames=selection)
    assert list(masks) == ["frame_0001"]
    assert (masks["frame_0001"].width, masks["frame_0001"].height, len(masks["frame_0001"])) == (
        20,
        16,
        1,
    )


def test_file_names_with_a_part_after_the_frame_name_are_the_frame_s(tmp_path: Path) -> None:
    data = coco([{"id": 1, "image_id": 2, "segmentation": [SQUARE]}], n_images=3)
    for image in data["images"]:
        image["file_name"] = image["file_name"].replace(".jpg", ".segm.jpg")
    index = write_json(tmp_path / "instances.json", data)
    frames = frozenset({"frame_0000", "frame_0001", "frame_0002"})
    masks = read_agnostic_masks(index, frames=FrameSelection(frozenset({"frame_0001"}), frames))
    assert list(masks) == ["frame_0001"] and len(masks["frame_0001"]) == 1


def test_image_without_annotations_has_no_masks(tmp_path: Path) -> None:
    write_json(tmp_path / "m" / "coco.json", coco([]))
    masks = read_agnostic_masks(tmp_path / "m")
    assert [(len(m), m.width, m.height) for m in masks.values()] == [(0, 10, 8), (0, 10, 8)]


def test_error_polygon_with_two_points_names_file_annotation_and_field(tmp_path: Path) -> None:
    annotations: list[dict[str, Any]] = [
        {"id": 7, "image_id": 1, "segmentation": [SQUARE, [1, 1, 3, 3]]},
        {"id": 8, "image_id": 1, "segmentation": [[1, 2, 3]]},
        {"id": 9, "image_id": 5, "segmentation": [SQUARE]},
        {"id": 10, "image_id": 2, "segmentation": rle_of(np.ones((4, 4), bool))},
        {"image_id": 2, "segmentation": [["a", 1, 2, 3, 4, 5]]},
        {"id": 12, "image_id": 2},
    ]
    write_json(tmp_path / "m" / "coco.json", coco(annotations))
    with pytest.raises(InputError) as info:
        read_agnostic_masks(tmp_path / "m")
    assert [str(p) for p in info.value.problems] == [
        "m/coco.json: annotations[2] (id 9): image_id 5 is not in 'images'",
        "m/coco.json: annotations[0] (id 7): segmentation[1] has 2 points; a polygon needs at "
        "least 3",
        "m/coco.json: annotations[1] (id 8): segmentation[0] has an odd number of coordinates (3)",
        "m/coco.json: annotations[3] (id 10): segmentation RLE is 4x4, image is 10x8",
        "m/coco.json: annotations[4]: segmentation[0] must be a list of numbers "
        "[x1, y1, x2, y2, ...]",
        "m/coco.json: annotations[5] (id 12): segmentation must be polygons [[x1, y1, ...], ...] "
        "or an RLE",
    ]


def test_error_polygon_far_outside_the_image_is_named_not_rasterised(tmp_path: Path) -> None:
    """pycocotools crashes the process (segfault) on a vertex like 1e11: refused first."""
    far = [2.0, 1.0, 99999999999.0, 1.0, 7.0, 5.0]
    annotations = [{"id": 7, "image_id": 1, "category_id": 1, "segmentation": [SQUARE, far]}]
    write_json(tmp_path / "m" / "coco.json", coco(annotations))
    with pytest.raises(InputError) as info:
        read_agnostic_masks(tmp_path / "m")
    assert str(info.value) == (
        "m/coco.json: annotations[0] (id 7): segmentation[1] point 2 (1e+11, 1) lies beyond the "
        "10x8 image by more than its size"
    )
    with pytest.raises(InputError, match=r"segmentation\[1\] point 2 \(1e\+11, 1\)"):
        read_semantic_maps(tmp_path / "m", Vocabulary(("chair",)))


def test_error_image_id_of_the_wrong_type_is_named(tmp_path: Path) -> None:
    annotations = [{"id": 7, "image_id": {"a": 1}, "segmentation": [SQUARE]}]
    write_json(tmp_path / "m" / "coco.json", coco(annotations))
    with pytest.raises(InputError) as info:
        read_agnostic_masks(tmp_path / "m")
    assert str(info.value) == (
        "m/coco.json: annotations[0] (id 7): image_id {'a': 1} is not in 'images'"
    )


def test_polygon_a_little_outside_the_image_is_clipped_as_pycocotools_does(
    tmp_path: Path,
) -> None:
    spill = [-3.0, -2.0, 12.0, -2.0, 12.0, 4.0, -3.0, 4.0]
    annotations = [{"id": 7, "image_id": 1, "category_id": 1, "segmentation": [spill]}]
    write_json(tmp_path / "m" / "coco.json", coco(annotations, n_images=1))
    dense = decode_masks(read_agnostic_masks(tmp_path / "m")["frame_0000"])
    np.testing.assert_array_equal(dense[0], reference([spill], 8, 10))
    assert dense[0].any()


def test_error_images_fields(tmp_path: Path) -> None:
    data = coco([])
    data["images"] += [{"id": 9, "file_name": "x.jpg", "height": 0, "width": 4}]
    data["images"] += [{"id": 1, "file_name": "y.jpg", "height": 2, "width": 4}]
    data["images"] += [{"id": 5, "file_name": "z.jpg", "height": 99999999999, "width": 10}]
    write_json(tmp_path / "m" / "coco.json", data)
    with pytest.raises(InputError) as info:
        read_agnostic_masks(tmp_path / "m")
    assert [str(p) for p in info.value.problems] == [
        "m/coco.json: images[2]: missing or invalid height",
        "m/coco.json: images[3]: frame 'y' or id listed twice",
        f"m/coco.json: images[4]: 10x99999999999 is above the limit of {MAX_PIXELS:,} pixels",
    ]


def test_error_rle_larger_than_an_image_may_be(tmp_path: Path) -> None:
    """A few bytes of RLE can claim 10^10 pixels: refused before anything is decoded."""
    bomb = {"size": [100000, 100000], "counts": [10**10]}
    annotations = [{"id": 3, "image_id": 1, "segmentation": bomb}]
    write_json(tmp_path / "m" / "coco.json", coco(annotations))
    with pytest.raises(InputError) as info:
        read_agnostic_masks(tmp_path / "m")
    assert str(info.value) == (
        "m/coco.json: annotations[0] (id 3): segmentation: RLE size 100000x100000 is above the "
        f"limit of {MAX_PIXELS:,} pixels"
    )


def test_error_not_coco_and_malformed_json(tmp_path: Path) -> None:
    write_json(tmp_path / "a.json", {"annotations": 3})
    with pytest.raises(InputError, match="a.json: expected a COCO JSON object with an"):
        read_agnostic_masks(tmp_path / "a.json")
    (tmp_path / "b.json").write_text('{"annotations": [', encoding="utf-8")
    with pytest.raises(InputError, match="b.json: malformed JSON at line 1"):
        read_agnostic_masks(tmp_path / "b.json")
    (tmp_path / "c.txt").write_text("x", encoding="utf-8")
    with pytest.raises(InputError, match="expected a folder of masks or a COCO JSON file"):
        read_agnostic_masks(tmp_path / "c.txt")


def test_class_maps_paint_categories_smaller_on_top(tmp_path: Path) -> None:
    """``categories`` names map to the vocabulary; a small object on a large one keeps its
    class whatever the annotation order; pixels without annotation are unlabelled."""
    table = np.zeros((8, 10), bool)
    table[2:8, 0:10] = True
    cup = np.zeros((8, 10), bool)
    cup[3:5, 4:6] = True
    annotations = [
        {"id": 1, "image_id": 1, "category_id": 62, "segmentation": rle_of(cup)},
        {"id": 2, "image_id": 1, "category_id": 67, "segmentation": rle_of(table)},
        {"id": 3, "image_id": 2, "category_id": 62, "segmentation": [SQUARE]},
    ]
    data = coco(annotations)
    data["categories"] = [{"id": 62, "name": "cup"}, {"id": 67, "name": "table"}]
    write_json(tmp_path / "m" / "coco.json", data)
    maps = read_semantic_maps(tmp_path / "m", Vocabulary(("wall", "table", "cup")))
    expected = np.full((8, 10), -1)
    expected[table] = 1
    expected[cup] = 2
    np.testing.assert_array_equal(maps["frame_0000"].classes, expected)
    np.testing.assert_array_equal(maps["frame_0001"].classes == 2, reference([SQUARE], 8, 10))
    assert maps["frame_0000"].source == "m/coco.json"
    small = read_semantic_maps(tmp_path / "m", Vocabulary(("wall", "table", "cup")), size=(5, 4))
    assert small["frame_0000"].classes.shape == (4, 5)


def test_class_map_errors_name_the_annotation(tmp_path: Path) -> None:
    annotations = [
        {"id": 1, "image_id": 1, "category_id": 5, "segmentation": [SQUARE]},
        {"id": 2, "image_id": 1, "segmentation": [SQUARE]},
        {"id": 3, "image_id": 2, "category_id": 0, "segmentation": [SQUARE]},
    ]
    data = coco(annotations)
    del data["categories"]  # category_id is the vocabulary index
    write_json(tmp_path / "m" / "coco.json", data)
    with pytest.raises(InputError) as info:
        read_semantic_maps(tmp_path / "m", Vocabulary(("chair",)))
    assert [str(p) for p in info.value.problems] == [
        "m/coco.json: annotations[0] (id 1): category_id 5 is beyond the vocabulary of 1 classes "
        "(without 'categories', category_id is the vocabulary index)",
        "m/coco.json: annotations[1] (id 2): category_id must be a non-negative integer, got None",
    ]
