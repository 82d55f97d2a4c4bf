"""[M, H, W] stacks of binary masks (.npy / .npz) and score filtering (SAM JSON, COCO, .npz)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pycocotools.mask as mask_util
import pytest

from dcseg.errors import InputError
from dcseg.io.mask_formats import describe_layout, detect_masks
from dcseg.io.mask_formats.scores import MinScores
from dcseg.io.masks import decode_masks, read_agnostic_masks
from tests.dcseg.io.mask_files import write_json


def stack() -> np.ndarray:
    """Three masks and an empty one, [4, 6, 8] bool."""
    masks = np.zeros((4, 6, 8), dtype=bool)
    masks[0, 1:4, 2:6] = True
    masks[1, 2:6, 0:3] = True
    masks[3] = True
    return masks


def test_npy_bool_and_uint8_stacks(tmp_path: Path) -> None:
    masks = stack()
    np.save(tmp_path / "a.npy", masks)
    np.save(tmp_path / "b.npy", masks.astype(np.uint8) * 255)
    np.save(tmp_path / "c.npy", masks[:, None].astype(np.uint8))  # SAM predictor [M, 1, H, W]
    read = read_agnostic_masks(tmp_path)
    for stem in "abc":
        np.testing.assert_array_equal(decode_masks(read[stem]), masks[[0, 1, 3]])
    assert describe_layout(detect_masks(tmp_path)) == "per-frame: NPY mask stack x3"


def test_npz_scores_filter_masks_default_keeps_all(tmp_path: Path) -> None:
    masks = stack()
    np.savez(
        tmp_path / "f.npz",
        masks=masks,
        scores=np.array([0.9, 0.3, 0.8, 0.5]),
        predicted_iou=np.array([0.99, 0.99, 0.99, 0.7], np.float32),
    )
    assert len(read_agnostic_masks(tmp_path)["f"]) == 3
    kept = read_agnostic_masks(tmp_path, min_scores=MinScores(score=0.4))["f"]
    np.testing.assert_array_equal(decode_masks(kept), masks[[0, 3]])
    kept = read_agnostic_masks(tmp_path, min_scores=MinScores(score=0.4, predicted_iou=0.8))["f"]
    np.testing.assert_array_equal(decode_masks(kept), masks[[0]])


def test_npz_rescaled_and_described(tmp_path: Path) -> None:
    np.savez_compressed(tmp_path / "f.npz", masks=stack())
    read = read_agnostic_masks(tmp_path, size=(16, 12))["f"]
    assert (read.width, read.height, len(read)) == (16, 12, 3)
    assert describe_layout(detect_masks(tmp_path)) == "per-frame: NPZ mask stack x1"


def sam_records(masks: np.ndarray, ious: list[float], stabilities: list[float]) -> list[Any]:
    records = []
    for mask, iou, stability in zip(masks, ious, stabilities, strict=True):
        rle = mask_util.encode(np.asfortranarray(mask.astype(np.uint8)))
        segmentation = {"size": rle["size"], "counts": rle["counts"].decode()}
        records.append(
            {"segmentation": segmentation, "predicted_iou": iou, "stability_score": stability}
        )
    return records


def test_sam_json_predicted_iou_and_stability_filter(tmp_path: Path) -> None:
    masks = stack()[:3]
    write_json(tmp_path / "f.json", sam_records(masks, [0.95, 0.89, 0.99], [0.97, 0.99, 0.90]))
    assert len(read_agnostic_masks(tmp_path)["f"]) == 2  # the empty mask is dropped
    kept = read_agnostic_masks(tmp_path, min_scores=MinScores(predicted_iou=0.9))["f"]
    np.testing.assert_array_equal(decode_masks(kept), masks[[0]])
    kept = read_agnostic_masks(tmp_path, min_scores=MinScores(stability_score=0.98))["f"]
    np.testing.assert_array_equal(decode_masks(kept), masks[[1]])


def test_coco_score_filter(tmp_path: Path) -> None:
    square = [[1, 1, 5, 1, 5, 4, 1, 4]]
    data = {
        "images": [{"id": 1, "file_name": "f.jpg", "height": 6, "width": 8}],
        "annotations": [
            {"id": 1, "image_id": 1, "segmentation": square, "score": 0.2},
            {"id": 2, "image_id": 1, "segmentation": square, "score": 0.7},
            {"id": 3, "image_id": 1, "segmentation": square},
        ],
    }
    write_json(tmp_path / "m" / "coco.json", data)
    assert len(read_agnostic_masks(tmp_path / "m")["f"]) == 3
    assert len(read_agnostic_masks(tmp_path / "m", min_scores=MinScores(score=0.5))["f"]) == 2


def test_error_bad_scores_named(tmp_path: Path) -> None:
    records = sam_records(stack()[:2], [0.9, 0.9], [0.9, 0.9])
    records[1]["predicted_iou"] = "high"
    write_json(tmp_path / "m" / "f.json", records)
    data = {
        "images": [{"id": 1, "file_name": "g.jpg", "height": 6, "width": 8}],
        "annotations": [
            {"id": 4, "image_id": 1, "segmentation": [[1, 1, 5, 1, 5, 4]], "score": None}
        ],
    }
    write_json(tmp_path / "c" / "coco.json", data)
    with pytest.raises(InputError, match=r"m/f.json: record 1: 'predicted_iou' must be a number"):
        read_agnostic_masks(tmp_path / "m")
    with pytest.raises(InputError, match=r"annotations\[0\] \(id 4\): 'score' must be a number"):
        read_agnostic_masks(tmp_path / "c")


def test_error_malformed_stacks(tmp_path: Path) -> None:
    np.savez(tmp_path / "a.npz", segmentation=stack())
    np.savez(tmp_path / "b.npz", masks=stack(), scores=np.ones(3))
    np.save(tmp_path / "c.npy", stack().astype(np.float32))
    (tmp_path / "d.npz").write_bytes(b"not a zip")
    with pytest.raises(InputError) as info:
        read_agnostic_masks(tmp_path)
    reasons = [str(p) for p in info.value.problems]
    name = tmp_path.name
    assert reasons[0] == f"{name}/a.npz: expected a 'masks' array (found: segmentation)"
    assert reasons[1] == f"{name}/b.npz: 'scores' must hold one number per mask (4), got shape (3,)"
    assert reasons[2] == (
        f"{name}/c.npy: expected [M, H, W] bool or uint8 masks, got shape (4, 6, 8) float32"
    )
    assert reasons[3].startswith(f"{name}/d.npz: cannot read mask stack")


def test_min_scores_bounds() -> None:
    with pytest.raises(ValueError, match="predicted_iou threshold must be in"):
        MinScores(predicted_iou=1.5)


def test_sam_json_records_roundtrip_through_npz(tmp_path: Path) -> None:
    masks = stack()
    write_json(tmp_path / "j" / "f.json", sam_records(masks, [0.9] * 4, [0.9] * 4))
    (tmp_path / "z").mkdir()
    np.savez(tmp_path / "z" / "f.npz", masks=masks)
    a = decode_masks(read_agnostic_masks(tmp_path / "j")["f"])
    b = decode_masks(read_agnostic_masks(tmp_path / "z")["f"])
    np.testing.assert_array_equal(a, b)
    assert json.loads((tmp_path / "j" / "f.json").read_text())[0]["predicted_iou"] == 0.9


def test_npz_shape_charged_before_decompressing(tmp_path: Path) -> None:
    from dcseg.io.images import pixel_budget

    np.savez_compressed(tmp_path / "f.npz", masks=np.zeros((50, 100, 100), bool))
    assert (tmp_path / "f.npz").stat().st_size < 10_000
    with pixel_budget(400_000), pytest.raises(InputError, match="pixels in total"):
        read_agnostic_masks(tmp_path)
    with pixel_budget(500_000):
        assert len(read_agnostic_masks(tmp_path)["f"]) == 0


def test_job_options_set_the_thresholds_of_the_train_stage() -> None:
    from dcseg.io.mask_formats.scores import min_scores
    from dcseg.options import build_config, parse_options
    from dcseg.stages import TRAIN, key_of

    options = {"affinity": {"min_predicted_iou": 0.9, "min_mask_score": 0.3}}
    config = build_config("fast", parse_options(options))
    assert min_scores(config.pipeline.affinity) == MinScores(0.3, 0.9, 0.0)
    default = build_config("fast", parse_options({}))
    assert min_scores(default.pipeline.affinity) == MinScores()
    assert key_of(TRAIN, config, {}) != key_of(TRAIN, default, {})  # no reuse across thresholds
    with pytest.raises(InputError) as info:
        parse_options({"affinity": {"min_stability_score": 1.5}})
    assert "min_stability_score" in str(info.value)


def grounded_sam2_result(masks: np.ndarray, scores: list[float]) -> dict[str, Any]:
    """One image's result as Grounded-SAM-2's demo writes it (``single_mask_to_rle``)."""
    annotations = []
    for mask, score in zip(masks, scores, strict=True):
        rle = mask_util.encode(np.array(mask[:, :, None], order="F", dtype="uint8"))[0]
        rle["counts"] = rle["counts"].decode("utf-8")
        annotations.append(
            {"class_name": "chair", "bbox": [0, 0, 1, 1], "segmentation": rle, "score": score}
        )
    height, width = masks.shape[1:]
    return {
        "image_path": "frames/f.jpg",
        "annotations": annotations,
        "box_format": "xyxy",
        "img_width": width,
        "img_height": height,
    }


@pytest.mark.parametrize("frames", [1, 2])
def test_grounded_sam2_per_frame_results(tmp_path: Path, frames: int) -> None:
    masks = stack()[:2]
    for i in range(frames):
        write_json(tmp_path / f"f{i}.json", grounded_sam2_result(masks, [0.8, 0.3]))
    assert describe_layout(detect_masks(tmp_path)) == f"per-frame: Grounded-SAM JSON x{frames}"
    read = read_agnostic_masks(tmp_path)
    np.testing.assert_array_equal(decode_masks(read["f0"]), masks)
    kept = read_agnostic_masks(tmp_path, min_scores=MinScores(score=0.5))["f0"]
    np.testing.assert_array_equal(decode_masks(kept), masks[[0]])


def test_run_flags_set_the_thresholds() -> None:
    from dcseg.cli import build_parser
    from dcseg.cli._pipeline import job_config
    from dcseg.io.mask_formats.scores import min_scores

    args = ["run", "c", "--agnostic-masks", "a", "--semantic-masks", "s", "--vocabulary", "v"]
    parsed = build_parser().parse_args(
        [*args, "--out", "o", "--min-predicted-iou", "0.9", "--min-stability-score", "0.95"]
    )
    assert min_scores(job_config(parsed).pipeline.affinity) == MinScores(0.0, 0.9, 0.95)
    with pytest.raises(SystemExit, match="--min-mask-score"):
        job_config(build_parser().parse_args([*args, "--out", "o", "--min-mask-score", "2"]))


def test_error_sam_record_larger_than_an_image_may_be(tmp_path: Path) -> None:
    """A SAM record's RLE gives its image's size: a few bytes can claim 3.6e9 pixels."""
    bomb = {"size": [60000, 60000], "counts": [60000 * 60000]}
    write_json(tmp_path / "f.json", [{"segmentation": bomb}])
    with pytest.raises(InputError, match=r"f\.json.*RLE size 60000x60000 is above the limit"):
        read_agnostic_masks(tmp_path)
