"""Microsoft 7-Scenes layout."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest

from dcseg.config import CaptureOptions
from dcseg.errors import InputError
from dcseg.io.captures import detect_layout, read_capture
from dcseg.io.images import write_image
from dcseg.types import Intrinsics
from tests.dcseg.io.layouts import (
    RgbdScene,
    assert_same_frames,
    make_scene,
    scene_capture,
    write_7scenes,
)

OPTIONS = CaptureOptions(intrinsics=(20.0, 22.0, 7.5, 5.5))


def test_smoke_root_files(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = write_7scenes(rgbd_scene, tmp_path)
    assert detect_layout(root) == "7scenes"
    capture = read_capture(root, OPTIONS)
    assert capture.names == tuple(f"frame-{i:06d}" for i in range(4))
    assert_same_frames(capture.frames, scene_capture(rgbd_scene).frames, pose_atol=1e-12)


def test_sequences_and_invalid_depth(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    write_7scenes(rgbd_scene, tmp_path, "seq-02")
    write_7scenes(make_scene(n=2, seed=1), tmp_path, "seq-01")
    raw = np.full((12, 16), 1500, np.uint16)
    raw[2, 3] = 65535
    write_image(tmp_path / "seq-01" / "frame-000001.depth.png", raw)
    capture = read_capture(tmp_path, OPTIONS)
    assert capture.names == (
        "seq-01/frame-000000",
        "seq-01/frame-000001",
        *(f"seq-02/frame-{i:06d}" for i in range(4)),
    )
    depth = capture.frames[1].depth
    assert depth[2, 3] == 0.0 and depth[0, 0] == pytest.approx(1.5)
    assert capture.frames[1].files["pose"] == "seq-01/frame-000001.pose.txt"


def test_default_intrinsics_for_640x480(tmp_path: Path, caplog) -> None:
    write_7scenes(make_scene(n=2, width=640, height=480), tmp_path)
    with caplog.at_level(logging.INFO):
        capture = read_capture(tmp_path, CaptureOptions(size=(320, 240)))
    assert "default Kinect intrinsics" in caplog.text
    expected = Intrinsics(585.0, 585.0, 320.0, 240.0, 640, 480).scaled(320, 240)
    assert capture.frames[0].intrinsics == expected


def test_other_sizes_need_intrinsics(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    write_7scenes(rgbd_scene, tmp_path)
    with pytest.raises(
        InputError,
        match=r"frame-000000\.color\.png: 7-Scenes images of 16x12 "
        r"need explicit intrinsics",
    ):
        read_capture(tmp_path)


def test_missing_parts(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    write_7scenes(rgbd_scene, tmp_path, "seq-01")
    (tmp_path / "seq-01" / "frame-000001.pose.txt").unlink()
    (tmp_path / "seq-01" / "frame-000002.depth.png").unlink()
    with pytest.raises(InputError) as info:
        read_capture(tmp_path, OPTIONS)
    assert [str(p) for p in info.value.problems] == [
        "seq-01/frame-000001.pose.txt: missing (colour seq-01/frame-000001.color.png has no pose)",
        "seq-01/frame-000002.depth.png: missing (colour seq-01/frame-000002.color.png has no "
        "depth)",
    ]
