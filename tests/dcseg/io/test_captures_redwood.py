"""Redwood / Open3D layout: ``.log`` trajectories written per
http://redwood-data.org/indoor/fileformat.html, intrinsics as Open3D's PinholeCameraIntrinsic
JSON (``intrinsic_matrix`` column-major)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from dcseg.config import CaptureOptions
from dcseg.errors import InputError
from dcseg.io.captures import detect_layout, read_capture
from dcseg.io.images import write_image
from dcseg.types import Intrinsics
from tests.dcseg.io.archived import check_zip_with_options
from tests.dcseg.io.layouts import (
    RgbdScene,
    assert_same_frames,
    check_synth_round_trip,
    check_validate_names_layout,
    make_scene,
    mm,
    scene_capture,
)

OPTIONS = CaptureOptions(intrinsics=(20.0, 22.0, 7.5, 5.5))


def log_text(poses: list[np.ndarray], numbers: list[int] | None = None) -> str:
    """Items of ``i i n`` metadata (Open3D writes n = i + 1) and four matrix rows."""
    lines = []
    for i, pose in enumerate(poses):
        n = numbers[i] if numbers else i + 1
        lines.append(f"{i} {i} {n}")
        lines.extend(" ".join(f"{v:.17g}" for v in row) for row in pose)
    return "\n".join(lines) + "\n"


def intrinsic_json(k: Intrinsics) -> dict[str, object]:
    matrix = [k.fx, 0.0, 0.0, 0.0, k.fy, 0.0, k.cx, k.cy, 1.0]  # column-major
    return {"width": k.width, "height": k.height, "intrinsic_matrix": matrix}


def write_redwood(
    scene: RgbdScene, root: Path, colour: str = "image", log: str = "trajectory.log"
) -> Path:
    """Open3D's reconstruction-system input: differently named colour and depth files."""
    for i in range(scene.n):
        write_image(root / colour / f"{i:06d}.png", scene.rgb[i])
        write_image(root / "depth" / f"{i + 1:07d}-{1000 * i:012d}.png", mm(scene.depth[i]))
    (root / log).write_text(log_text(scene.c2w))
    (root / "camera_intrinsic.json").write_text(json.dumps(intrinsic_json(scene.k)))
    return root


def test_round_trip(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = write_redwood(rgbd_scene, tmp_path)
    assert detect_layout(root) == "redwood"
    capture = read_capture(root)
    assert capture.layout == "redwood"
    assert capture.names == tuple(f"{i:06d}" for i in range(4))
    assert_same_frames(capture.frames, scene_capture(rgbd_scene).frames, pose_atol=1e-12)
    assert capture.frames[1].files["pose"] == "trajectory.log:line 6"
    assert capture.frames[1].files["intrinsics"] == "camera_intrinsic.json"


def test_subset_other_names_and_options_intrinsics(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = write_redwood(rgbd_scene, tmp_path, colour="color", log="odometry.log")
    (root / "camera_intrinsic.json").unlink()
    (root / "odometry.log").write_text(log_text([rgbd_scene.c2w[2], rgbd_scene.c2w[0]], [3, 1]))
    capture = read_capture(root, OPTIONS)
    assert capture.names == ("000002", "000000")
    np.testing.assert_allclose(capture.frames[0].c2w, rgbd_scene.c2w[2], atol=1e-12)
    np.testing.assert_allclose(capture.frames[0].depth, rgbd_scene.depth[2], atol=1e-6)
    with pytest.raises(InputError, match=r"no intrinsics: add camera_intrinsic\.json"):
        read_capture(root)


def test_scene_trajectory_and_several_logs(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = write_redwood(rgbd_scene, tmp_path, log="a.log")
    (root / "b.log").write_text(log_text(rgbd_scene.c2w))
    with pytest.raises(InputError, match=r"several \.log trajectories \(a\.log, b\.log\)"):
        read_capture(root)
    (root / "scene").mkdir()
    (root / "scene" / "trajectory.log").write_text(log_text(rgbd_scene.c2w))
    frame = read_capture(root).frames[0]
    assert frame.files["pose"] == "scene/trajectory.log:line 1"


def test_malformed_trajectory(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = write_redwood(rgbd_scene, tmp_path)
    log = root / "trajectory.log"
    lines = log.read_text().splitlines()
    cases = [
        (7, "0.5 0.5 0.5", "trajectory.log:line 7: expected a matrix row of 4 numbers, got 3"),
        (7, "0.5 0.5 x 1", "trajectory.log:line 7: matrix row must be numbers, got ['0.5', "),
        (6, "1 1", "trajectory.log:line 6: expected 3 integers of metadata (the third is the "),
        (6, "1 1 0", "trajectory.log:line 6: frame number 0 must be >= 1 (counted from 1)"),
        (6, "1 1 9", "trajectory.log:line 6: frame number 9 but there are 4 image pairs"),
    ]
    for number, text, message in cases:
        edited = list(lines)
        edited[number - 1] = text
        log.write_text("\n".join(edited) + "\n")
        with pytest.raises(InputError) as info:
            read_capture(root)
        assert str(info.value).startswith(message), (text, str(info.value))
    log.write_text("\n".join(lines[:-2]) + "\n")
    with pytest.raises(InputError) as info:
        read_capture(root)
    assert str(info.value) == (
        "trajectory.log:line 16: truncated item: a metadata line and 4 matrix rows expected, "
        "got 3 lines"
    )
    edited = list(lines)
    edited[6] = "0 2 0 0"  # frame 1's first matrix row: not a rotation
    log.write_text("\n".join(edited) + "\n")
    with pytest.raises(InputError, match=r"trajectory\.log:line 6: pose is not a rigid"):
        read_capture(root)


def test_counts_and_intrinsics_file(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = write_redwood(rgbd_scene, tmp_path)
    (root / "camera_intrinsic.json").write_text(json.dumps({"width": 16, "intrinsic_matrix": [1]}))
    with pytest.raises(InputError, match=r"camera_intrinsic\.json: height: missing"):
        read_capture(root)
    (root / "camera_intrinsic.json").write_text(json.dumps({"width": 16, "height": 12}))
    with pytest.raises(InputError, match=r"camera_intrinsic\.json: intrinsic_matrix: missing"):
        read_capture(root)
    doc = {"width": 16, "height": 12, "intrinsic_matrix": [1, 2]}
    (root / "camera_intrinsic.json").write_text(json.dumps(doc))
    with pytest.raises(InputError, match=r"intrinsic_matrix: expected 9 finite numbers"):
        read_capture(root)
    (root / "camera_intrinsic.json").unlink()
    next((root / "depth").iterdir()).unlink()
    with pytest.raises(InputError, match=r"^depth/: 3 depth images but 4 colour images in image/"):
        read_capture(root, OPTIONS)


def test_stray_dataset_depth_scale_and_lower_resolution(tmp_path: Path) -> None:
    """Stray's dataset format: color/ + depth/ at a lower resolution (same aspect ratio), a
    depth_scale in camera_intrinsic.json, scene/trajectory.log from ``stray studio integrate``."""
    scene = make_scene(n=2)
    root = tmp_path / "stray"
    for i in range(scene.n):
        write_image(root / "color" / f"{i:06d}.jpg", scene.rgb[i])
        raw = np.rint(scene.depth[i] * 5000.0).astype(np.uint16)[::2, ::2]
        write_image(root / "depth" / f"{i:06d}.png", raw)
    (root / "scene").mkdir()
    (root / "scene" / "trajectory.log").write_text(log_text(scene.c2w))
    doc = {"depth_format": "Z16", "depth_scale": 5000.0, "fps": 60.0, **intrinsic_json(scene.k)}
    (root / "camera_intrinsic.json").write_text(json.dumps(doc))
    capture = read_capture(root)
    assert capture.layout == "redwood" and capture.names == ("000000", "000001")
    frame = capture.frames[1]
    assert frame.depth.shape == (12, 16)
    assert frame.depth[5, 7] == pytest.approx(scene.depth[1][4, 6], abs=1e-6)
    doc["depth_scale"] = 0
    (root / "camera_intrinsic.json").write_text(json.dumps(doc))
    with pytest.raises(InputError, match=r"camera_intrinsic\.json: depth_scale: must be > 0"):
        read_capture(root)


def test_zip_with_options(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    check_zip_with_options(rgbd_scene, write_redwood(rgbd_scene, tmp_path / "cap"), "redwood")


def test_validate_names_the_layout(tmp_path: Path) -> None:
    check_validate_names_layout(tmp_path, write_redwood, "redwood")


def test_synth_scene_as_redwood(tmp_path: Path) -> None:
    """A ``dcseg synth`` capture written as Redwood reads back the same."""
    check_synth_round_trip(tmp_path, write_redwood, pose_atol=1e-12)
