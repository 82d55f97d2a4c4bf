"""Polycam raw data exports written in code from the documented layout."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from dcseg.config import CaptureOptions
from dcseg.errors import InputError
from dcseg.inputs import RunInputs
from dcseg.io.captures import detect_layout, read_capture
from dcseg.io.images import write_image
from dcseg.io.validate import validate_inputs
from tests.dcseg.io.arkit_scene import (
    CX,
    CY,
    FX,
    FY,
    HEIGHT,
    VIEWS,
    WIDTH,
    View,
    arkit_matrix,
    assert_views_read,
    colour,
    confidence_map,
    depth_map,
)

STAMPS = ("9000", "10000", "10500")  # sorted numerically, not as text


def camera_json(view: View) -> dict[str, Any]:
    doc: dict[str, Any] = {"fx": FX, "fy": FY, "cx": CX, "cy": CY, "width": WIDTH,
                           "height": HEIGHT, "blur_score": 30.0, "timestamp": 1}  # fmt: skip
    pose = arkit_matrix(view)
    for row in range(3):
        for col in range(4):
            doc[f"t_{row}{col}"] = float(pose[row, col])
    return doc


def write_polycam(root: Path, corrected: bool = False) -> Path:
    keyframes = root / "keyframes"
    images, cameras = (
        ("corrected_images", "corrected_cameras") if corrected else ("images", "cameras")
    )
    for stamp, (i, view) in zip(STAMPS, enumerate(VIEWS), strict=True):
        write_image(keyframes / images / f"{stamp}.jpg", colour(i))
        (keyframes / cameras).mkdir(parents=True, exist_ok=True)
        (keyframes / cameras / f"{stamp}.json").write_text(json.dumps(camera_json(view)))
        millimetres = np.rint(depth_map(view) * 1000).astype(np.uint16)
        write_image(keyframes / "depth" / f"{stamp}.png", millimetres)
        write_image(keyframes / "confidence" / f"{stamp}.png", confidence_map())
    return root


@pytest.fixture
def polycam(tmp_path: Path) -> Path:
    return write_polycam(tmp_path / "scan")


def test_raw_export_is_detected_and_read(polycam: Path) -> None:
    assert detect_layout(polycam) == "polycam"
    capture = read_capture(polycam)
    assert capture.layout == "polycam"
    assert [f.name for f in capture.frames] == list(STAMPS)
    assert capture.frames[0].files["pose"] == "keyframes/cameras/9000.json"
    assert capture.frames[0].files["depth"] == "keyframes/depth/9000.png"
    assert_views_read(capture)


def test_corrected_images_and_cameras_are_preferred(polycam: Path) -> None:
    write_polycam(polycam, corrected=True)
    for path in (polycam / "keyframes" / "cameras").iterdir():
        path.write_text("{}")  # the uncorrected cameras must not be read
    capture = read_capture(polycam)
    assert capture.frames[0].files["rgb"] == "keyframes/corrected_images/9000.jpg"
    assert capture.frames[0].files["pose"] == "keyframes/corrected_cameras/9000.json"
    assert_views_read(capture)


def test_min_confidence_masks_depth(polycam: Path) -> None:
    kept = read_capture(polycam).frames[1].depth
    masked = read_capture(polycam, CaptureOptions(min_confidence=2)).frames[1]
    low = (confidence_map() < 2)[np.arange(HEIGHT) // 2][:, np.arange(WIDTH) // 2]
    assert np.all(masked.depth[low] == 0.0)
    np.testing.assert_array_equal(masked.depth[~low], kept[~low])
    assert masked.files["confidence"] == "keyframes/confidence/10000.png"
    assert np.count_nonzero(kept[low]) > 0


def _error(root: Path, options: CaptureOptions | None = None) -> str:
    with pytest.raises(InputError) as caught:
        read_capture(root, options or CaptureOptions())
    report = validate_inputs(RunInputs(capture=root), options)
    assert [str(p) for p in report.problems] == [str(p) for p in caught.value.problems]
    return str(caught.value)


def test_camera_file_problems_are_named_per_field(polycam: Path) -> None:
    cameras = polycam / "keyframes" / "cameras"
    doc = camera_json(VIEWS[0])
    del doc["t_13"]
    doc["fx"] = "wide"
    (cameras / "9000.json").write_text(json.dumps(doc))
    (cameras / "10000.json").unlink()
    (cameras / "10500.json").write_text("[1, 2")
    message = _error(polycam)
    assert "keyframes/cameras/9000.json: fx: must be a finite number, got 'wide'" in message
    assert "keyframes/cameras/9000.json: t_13: missing" in message
    assert (
        "keyframes/cameras/10000.json: missing (colour keyframes/images/10000.jpg has no camera)"
    ) in message
    assert "keyframes/cameras/10500.json: invalid JSON" in message


def test_pose_that_is_not_rigid_is_refused(polycam: Path) -> None:
    doc = camera_json(VIEWS[0])
    doc["t_00"] = 3.0
    (polycam / "keyframes" / "cameras" / "9000.json").write_text(json.dumps(doc))
    assert "keyframes/cameras/9000.json: pose is not a rigid transform" in _error(polycam)


def test_depth_and_size_problems(polycam: Path) -> None:
    keyframes = polycam / "keyframes"
    (keyframes / "depth" / "9000.png").unlink()
    write_image(keyframes / "depth" / "10000.png", np.zeros((9, 12, 3), np.uint8))
    write_image(keyframes / "images" / "10500.jpg", np.zeros((12, 16, 3), np.uint8))
    message = _error(polycam)
    assert (
        "keyframes/depth/9000.png: missing (colour keyframes/images/9000.jpg has no depth)"
        in message
    )
    assert "keyframes/depth/10000.png: depth must be a single-channel image" in message
    assert (
        "keyframes/cameras/10500.json: intrinsics are for 24x18 but the image "
        "keyframes/images/10500.jpg is 16x12"
    ) in message


def test_confidence_problems(polycam: Path) -> None:
    confidence = polycam / "keyframes" / "confidence"
    write_image(confidence / "9000.png", np.full((9, 12), 255, np.uint8))
    write_image(confidence / "10000.png", np.zeros((4, 4), np.uint8))
    (confidence / "10500.png").unlink()
    assert len(read_capture(polycam)) == 3  # confidence is not read without min_confidence
    message = _error(polycam, CaptureOptions(min_confidence=1))
    assert (
        "keyframes/confidence/9000.png: confidence values must be ARKit levels 0, 1 or 2, found 255"
    ) in message
    assert (
        "keyframes/confidence/10000.png: confidence size 4x4 does not match depth size 12x9 "
        "(keyframes/depth/10000.png)"
    ) in message
    assert "keyframes/confidence/10500.png: missing" in message
