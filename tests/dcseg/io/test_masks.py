"""Class-agnostic masks: SAM JSON / PNG-folder / label-map readers, helpers and the JSON writer."""

from __future__ import annotations

import csv
import json
import logging
import warnings
from pathlib import Path

import cv2
import numpy as np
import pycocotools.mask as mask_util
import pytest

from dcseg.errors import InputError
from dcseg.io.images import resize_nearest
from dcseg.io.masks import (
    decode_masks,
    mask_areas,
    masks_from_dense,
    masks_from_label_map,
    read_agnostic_masks,
    resize_masks,
    write_agnostic_json,
)

REAL_SAM = Path("/work/shared/data/replica_room0_small/sam_masks/frame000000.npy")
SAM_HEADER = (
    "id,area,bbox_x0,bbox_y0,bbox_w,bbox_h,point_input_x,point_input_y,predicted_iou,"
    "stability_score,crop_box_x0,crop_box_y0,crop_box_w,crop_box_h"
).split(",")


def dense_stack(height: int = 6, width: int = 8) -> np.ndarray:
    """Three overlapping masks plus one empty mask, [4, H, W] bool."""
    stack = np.zeros((4, height, width), dtype=bool)
    stack[0, 1:4, 2:6] = True
    stack[1, 2:6, 0:3] = True
    stack[2] = True
    return stack


def sam_record(mask: np.ndarray, **extra: object) -> dict[str, object]:
    """A record as SAM amg.py writes it with --convert-to-rle."""
    rle = mask_util.encode(np.asfortranarray(mask.astype(np.uint8)))
    record: dict[str, object] = {
        "segmentation": {"size": rle["size"], "counts": rle["counts"].decode()},
        "area": int(mask.sum()),
        "bbox": [0, 0, 1, 1],
        "predicted_iou": 0.9,
        "point_coords": [[1.0, 2.0]],
        "stability_score": 0.95,
        "crop_box": [0, 0, mask.shape[1], mask.shape[0]],
    }
    record.update(extra)
    return record


def write_sam_json(path: Path, stack: np.ndarray) -> None:
    path.write_text(json.dumps([sam_record(m) for m in stack]))


def write_sam_folder(folder: Path, stack: np.ndarray) -> None:
    """SAM amg.py non-RLE output: <id>.png (0/255) plus metadata.csv."""
    folder.mkdir(parents=True)
    with (folder / "metadata.csv").open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(SAM_HEADER)
        for i, mask in enumerate(stack):
            cv2.imwrite(str(folder / f"{i}.png"), mask.astype(np.uint8) * 255)
            writer.writerow([i, int(mask.sum())] + [0] * 12)


def error_of(folder: Path) -> InputError:
    with pytest.raises(InputError) as info:
        read_agnostic_masks(folder)
    return info.value


# --------------------------------------------------------------------------- round trips


def test_json_round_trip_drops_empty_and_keeps_rle_bytes(tmp_path: Path) -> None:
    stack = dense_stack()
    write_sam_json(tmp_path / "frame0.json", stack)
    masks = read_agnostic_masks(tmp_path)["frame0"]
    assert (masks.name, masks.height, masks.width, len(masks)) == ("frame0", 6, 8, 3)
    np.testing.assert_array_equal(decode_masks(masks), stack[:3])
    assert all(isinstance(r["counts"], bytes) for r in masks.rles)
    assert masks.source == f"{tmp_path.name}/frame0.json"


def test_json_uncompressed_rle_list_counts(tmp_path: Path) -> None:
    # Column-major runs over a 4x5 mask: 6 off, 2 on, 2 off, 2 on, 8 off.
    seg = {"size": [4, 5], "counts": [6, 2, 2, 2, 8]}
    (tmp_path / "a.json").write_text(json.dumps([{"segmentation": seg}]))
    masks = read_agnostic_masks(tmp_path)["a"]
    expected = np.zeros((4, 5), dtype=bool)
    expected[2:4, 1:3] = True
    np.testing.assert_array_equal(decode_masks(masks)[0], expected)
    assert isinstance(masks.rles[0]["counts"], bytes)


def test_write_agnostic_json_is_sam_format_and_round_trips(tmp_path: Path) -> None:
    masks = masks_from_dense("f", dense_stack())
    path = tmp_path / "out" / "f.json"
    write_agnostic_json(path, masks)
    records = json.loads(path.read_text())
    assert [r["area"] for r in records] == [12, 12, 48]
    assert records[0]["bbox"] == [2, 1, 4, 3]
    assert isinstance(records[0]["segmentation"]["counts"], str)
    assert records[0]["segmentation"]["size"] == [6, 8]
    again = read_agnostic_masks(path.parent)["f"]
    np.testing.assert_array_equal(decode_masks(again), decode_masks(masks))


def test_png_folder_with_metadata_round_trip(tmp_path: Path) -> None:
    stack = dense_stack()
    write_sam_folder(tmp_path / "frame0", stack)
    masks = read_agnostic_masks(tmp_path)["frame0"]
    assert (masks.height, masks.width, len(masks)) == (6, 8, 3)
    np.testing.assert_array_equal(decode_masks(masks), stack[:3])


@pytest.mark.parametrize("dtype,value", [(np.uint8, 200), (np.uint16, 40000)])
def test_label_map_png(tmp_path: Path, dtype: type, value: int) -> None:
    labels: np.ndarray = np.zeros((5, 7), dtype=dtype)
    labels[1:3, 1:4] = value
    labels[4, :] = 3
    cv2.imwrite(str(tmp_path / "f.png"), labels)
    masks = read_agnostic_masks(tmp_path)["f"]
    assert len(masks) == 2  # 0 = none
    np.testing.assert_array_equal(decode_masks(masks), [labels == 3, labels == value])


def test_label_map_npy_negative_is_none(tmp_path: Path) -> None:
    labels = np.full((4, 6), -100, dtype=np.int32)
    labels[0, :3] = 0
    labels[2:, 2:] = 7
    np.save(tmp_path / "f.npy", labels)
    masks = read_agnostic_masks(tmp_path)["f"]
    np.testing.assert_array_equal(decode_masks(masks), [labels == 0, labels == 7])


def test_several_frames_keyed_by_stem(tmp_path: Path) -> None:
    write_sam_json(tmp_path / "b.json", dense_stack())
    np.save(tmp_path / "a.npy", np.ones((6, 8), dtype=np.int16))
    (tmp_path / "notes.txt").write_text("ignored")
    (tmp_path / ".hidden.json").write_text("not json")
    out = read_agnostic_masks(tmp_path)
    assert list(out) == ["a", "b"]


def test_real_sam_label_map_has_39_masks() -> None:
    if not REAL_SAM.is_file():
        pytest.skip(f"real SAM result not available at {REAL_SAM}")
    masks = read_agnostic_masks(REAL_SAM.parent)["frame000000"]
    assert (len(masks), masks.height, masks.width) == (39, 680, 1200)
    assert all(isinstance(r["counts"], bytes) for r in masks.rles)


# --------------------------------------------------------------------------- rescaling


def test_resize_nearest_up_and_down() -> None:
    labels = np.arange(16, dtype=np.int32).reshape(4, 4)
    up = resize_nearest(labels, (8, 8))
    np.testing.assert_array_equal(up, np.repeat(np.repeat(labels, 2, axis=0), 2, axis=1))
    np.testing.assert_array_equal(resize_nearest(labels, (2, 2)), [[5, 7], [13, 15]])
    assert resize_nearest(labels, (4, 4)) is labels
    assert resize_nearest(labels, (6, 2)).shape == (2, 6)


def test_read_rescales_label_map_up_and_down(tmp_path: Path) -> None:
    labels = np.zeros((4, 4), dtype=np.uint8)
    labels[:2, :2] = 1
    labels[3, 3] = 2
    cv2.imwrite(str(tmp_path / "f.png"), labels)
    up = read_agnostic_masks(tmp_path, size=(8, 8))["f"]
    assert (up.width, up.height) == (8, 8)
    big = np.repeat(np.repeat(labels, 2, axis=0), 2, axis=1)
    np.testing.assert_array_equal(decode_masks(up), [big == 1, big == 2])
    down = read_agnostic_masks(tmp_path, size=(2, 2))["f"]
    expected = [[[True, False], [False, False]], [[False, False], [False, True]]]
    np.testing.assert_array_equal(decode_masks(down), expected)


def test_resize_masks_matches_resize_nearest_and_drops_vanished() -> None:
    stack = np.zeros((2, 4, 4), dtype=bool)
    stack[0, :2, :2] = True
    stack[1, 0, 0] = True  # not sampled at 2x2 (pixels 1 and 3 are)
    masks = masks_from_dense("f", stack)
    small = resize_masks(masks, (2, 2))
    assert (small.width, small.height, len(small)) == (2, 2, 1)
    np.testing.assert_array_equal(decode_masks(small)[0], resize_nearest(stack[0], (2, 2)))
    assert resize_masks(masks, (4, 4)) is masks


def test_json_read_with_size_rescales(tmp_path: Path) -> None:
    write_sam_json(tmp_path / "f.json", dense_stack(4, 4))
    masks = read_agnostic_masks(tmp_path, size=(8, 8))["f"]
    assert (masks.width, masks.height) == (8, 8)
    assert mask_areas(masks).tolist() == [
        4 * a for a in mask_areas(masks_from_dense("f", dense_stack(4, 4)))
    ]


# --------------------------------------------------------------------------- helpers


def test_helpers_on_dense_masks(caplog: pytest.LogCaptureFixture) -> None:
    stack = dense_stack()
    with caplog.at_level(logging.DEBUG, logger="dcseg.io.masks"):
        masks = masks_from_dense("f", stack, source="x")
    assert "dropped 1 empty mask" in caplog.text
    assert mask_areas(masks).dtype == np.int64
    assert mask_areas(masks).tolist() == [12, 12, 48]
    np.testing.assert_array_equal(decode_masks(masks, [2, 0]), stack[[2, 0]])
    assert decode_masks(masks, []).shape == (0, 6, 8)
    empty = masks_from_dense("e", np.zeros((0, 3, 5), dtype=bool))
    assert decode_masks(empty).shape == (0, 3, 5)
    assert mask_areas(empty).shape == (0,)


def test_decode_matches_pycocotools_on_random_masks() -> None:
    rng = np.random.default_rng(0)
    blobs = rng.random((5, 37, 91)) < np.linspace(0.01, 0.99, 5)[:, None, None]
    blobs[0, :30, :80] = True  # long runs need multi-character counts
    masks = masks_from_dense("f", blobs)
    with warnings.catch_warnings():  # pycocotools' decode warns under numpy 2
        warnings.simplefilter("ignore", DeprecationWarning)
        reference = mask_util.decode(list(masks.rles)).transpose(2, 0, 1).astype(bool)
    np.testing.assert_array_equal(decode_masks(masks), reference)
    np.testing.assert_array_equal(decode_masks(masks), blobs)


def test_masks_from_label_map_none_below() -> None:
    labels = np.array([[0, 1], [2, 2]])
    assert len(masks_from_label_map("f", labels)) == 3
    assert len(masks_from_label_map("f", labels, none_below=1)) == 2


def test_storage_is_compact(tmp_path: Path) -> None:
    masks = masks_from_dense("f", np.ones((3, 200, 300), dtype=bool))
    for rle in masks.rles:
        assert set(rle) == {"size", "counts"}
        assert isinstance(rle["counts"], bytes)
        assert len(rle["counts"]) < 100
    assert not any(isinstance(v, np.ndarray) for v in vars(masks).values())


# --------------------------------------------------------------------------- errors


def test_error_malformed_json_names_line_and_column(tmp_path: Path) -> None:
    (tmp_path / "f.json").write_text('[\n  {"segmentation": }\n]')
    err = error_of(tmp_path)
    assert str(err) == (
        f"{tmp_path.name}/f.json: malformed JSON at line 2, column 20: Expecting value"
    )


def test_error_json_not_a_list(tmp_path: Path) -> None:
    (tmp_path / "f.json").write_text('{"a": 1}')
    with pytest.raises(InputError, match="f.json: expected a JSON list of SAM mask records"):
        read_agnostic_masks(tmp_path)


def test_error_record_without_segmentation(tmp_path: Path) -> None:
    records = [sam_record(dense_stack()[0]), {"area": 3}]
    (tmp_path / "f.json").write_text(json.dumps(records))
    with pytest.raises(InputError, match=r"f\.json: record 1 has no 'segmentation'"):
        read_agnostic_masks(tmp_path)


def test_error_rle_size_disagrees(tmp_path: Path) -> None:
    records = [sam_record(np.ones((6, 8), bool)), sam_record(np.ones((5, 8), bool))]
    (tmp_path / "f.json").write_text(json.dumps(records))
    with pytest.raises(
        InputError, match=r"f\.json: record 1: RLE size 8x5 \(WxH\) disagrees with 8x6"
    ):
        read_agnostic_masks(tmp_path)


@pytest.mark.parametrize("counts", ["zzzz", "0", [1, 2], [-1, 21], "not ascii \u00e9", 5], ids=str)
def test_error_corrupt_rle_counts(tmp_path: Path, counts: object) -> None:
    seg = {"size": [4, 5], "counts": counts}
    (tmp_path / "f.json").write_text(json.dumps([{"segmentation": seg}]))
    with pytest.raises(InputError, match=r"f\.json: record 0: RLE counts"):
        read_agnostic_masks(tmp_path)


def test_error_bad_rle_size(tmp_path: Path) -> None:
    seg = {"size": [4], "counts": "0"}
    (tmp_path / "f.json").write_text(json.dumps([{"segmentation": seg}]))
    with pytest.raises(InputError, match=r"record 0: RLE size must be \[height, width\]"):
        read_agnostic_masks(tmp_path)


def test_error_bad_png_in_folder(tmp_path: Path) -> None:
    write_sam_folder(tmp_path / "f", dense_stack())
    (tmp_path / "f" / "1.png").write_bytes(b"not a png")
    err = error_of(tmp_path)
    assert [str(p) for p in err.problems] == [
        f"{tmp_path.name}/f/1.png: cannot decode image (corrupt or not an image)"
    ]


def test_error_metadata_missing(tmp_path: Path) -> None:
    write_sam_folder(tmp_path / "f", dense_stack())
    (tmp_path / "f" / "metadata.csv").unlink()
    with pytest.raises(InputError, match=r"f/metadata\.csv: metadata\.csv not found"):
        read_agnostic_masks(tmp_path)


def test_error_metadata_id_without_png(tmp_path: Path) -> None:
    write_sam_folder(tmp_path / "f", dense_stack())
    (tmp_path / "f" / "2.png").unlink()
    with pytest.raises(InputError, match=r"metadata\.csv: id '2' has no PNG \(2\.png not found\)"):
        read_agnostic_masks(tmp_path)


def test_error_png_sizes_differ_in_folder(tmp_path: Path) -> None:
    write_sam_folder(tmp_path / "f", dense_stack())
    cv2.imwrite(str(tmp_path / "f" / "3.png"), np.zeros((5, 5), np.uint8))
    with pytest.raises(InputError, match=r"f/3\.png: mask is 5x5 but 0\.png .* is 8x6"):
        read_agnostic_masks(tmp_path)


def test_error_same_stem_in_two_formats(tmp_path: Path) -> None:
    write_sam_json(tmp_path / "a.json", dense_stack())
    cv2.imwrite(str(tmp_path / "a.png"), np.ones((6, 8), np.uint8))
    name = tmp_path.name
    with pytest.raises(
        InputError, match=f"frame 'a' has masks in several formats: {name}/a.json, {name}/a.png"
    ):
        read_agnostic_masks(tmp_path)


def test_error_label_map_types(tmp_path: Path) -> None:
    cv2.imwrite(str(tmp_path / "rgb.png"), np.zeros((4, 4, 3), np.uint8))
    np.save(tmp_path / "float.npy", np.zeros((4, 4), np.float32))
    (tmp_path / "broken.npy").write_bytes(b"nope")
    reasons = sorted(str(p) for p in error_of(tmp_path).problems)
    assert len(reasons) == 3
    assert reasons[0].startswith(f"{tmp_path.name}/broken.npy: cannot read .npy array")
    assert (
        reasons[1] == f"{tmp_path.name}/float.npy: expected a 2D integer label map, got 2D float32"
    )
    assert reasons[2] == (
        f"{tmp_path.name}/rgb.png: expected a single-channel label map, got 3 channels"
    )


def test_error_missing_folder(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="mask folder not found"):
        read_agnostic_masks(tmp_path / "nope")


def test_metadata_problems(tmp_path: Path) -> None:
    folder = tmp_path / "f"
    write_sam_folder(folder, dense_stack())
    meta = folder / "metadata.csv"
    meta.write_text("id,area\n0,1\n0,1\n")
    with pytest.raises(InputError, match=r"f/metadata\.csv: id '0' is listed more than once"):
        read_agnostic_masks(tmp_path)
    meta.write_text("name,area\n0,1\n")
    with pytest.raises(InputError, match=r"metadata\.csv has no 'id' column"):
        read_agnostic_masks(tmp_path)
    meta.write_text("id,area\n../f/0,1\n")
    with pytest.raises(InputError, match=r"ids must be plain file stems, got \['../f/0'\]"):
        read_agnostic_masks(tmp_path)


def test_png_folder_rejects_colour_masks(tmp_path: Path) -> None:
    write_sam_folder(tmp_path / "f", dense_stack())
    cv2.imwrite(str(tmp_path / "f" / "0.png"), np.zeros((6, 8, 3), np.uint8))
    with pytest.raises(
        InputError, match=r"f/0\.png: expected a single-channel binary mask, got 3 channels"
    ):
        read_agnostic_masks(tmp_path)


def test_empty_json_list(tmp_path: Path) -> None:
    (tmp_path / "f.json").write_text("[]")
    masks = read_agnostic_masks(tmp_path)["f"]
    assert (len(masks), masks.width, masks.height) == (0, 0, 0)
    sized = read_agnostic_masks(tmp_path, size=(8, 6))["f"]
    assert (len(sized), sized.width, sized.height) == (0, 8, 6)


def test_error_every_bad_record_is_reported(tmp_path: Path) -> None:
    records = [
        "not a record",
        {"segmentation": [[0, 0, 1, 1, 2, 0]]},
        {"segmentation": {"size": [4, 5], "counts": {"a": 1}}},
    ]
    (tmp_path / "f.json").write_text(json.dumps(records))
    reasons = [p.reason for p in error_of(tmp_path).problems]
    assert reasons == [
        "record 0 has no 'segmentation'",
        "record 1: segmentation must be a COCO RLE with 'size' and 'counts'",
        "record 2: RLE counts must be a string or a list, got dict",
    ]


def test_resize_masks_rejects_bad_size() -> None:
    with pytest.raises(ValueError, match="size must be positive"):
        resize_masks(masks_from_dense("f", dense_stack()), (0, 3))
