"""ScanNet export layout."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest

from dcseg.config import CaptureOptions
from dcseg.errors import InputError
from dcseg.io.captures import detect_layout, read_capture
from dcseg.io.images import write_image
from tests.dcseg.io.layouts import (
    RgbdScene,
    assert_same_frames,
    make_scene,
    scene_capture,
    write_scannet,
)


def test_smoke(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = write_scannet(rgbd_scene, tmp_path / "scan")
    assert detect_layout(root) == "scannet"
    capture = read_capture(root)
    assert capture.layout == "scannet"
    assert capture.names == ("0", "1", "2", "3")
    assert_same_frames(capture.frames, scene_capture(rgbd_scene).frames, pose_atol=1e-12)
    for i, frame in enumerate(capture.frames):
        assert frame.files == {
            "rgb": f"color/{i}.png",
            "depth": f"depth/{i}.png",
            "pose": f"pose/{i}.txt",
            "intrinsics": "intrinsic/intrinsic_color.txt",
        }


def test_numeric_order_and_jpeg(tmp_path: Path) -> None:
    scene = make_scene(n=12)
    root = write_scannet(scene, tmp_path, ext=".jpg")
    write_image(root / "color" / "0.jpg", np.full((12, 16, 3), (200, 60, 10), np.uint8))
    capture = read_capture(root)
    assert capture.names == tuple(str(i) for i in range(12))
    mean_rgb = capture.frames[0].rgb.reshape(-1, 3).mean(axis=0)
    np.testing.assert_allclose(mean_rgb, (200, 60, 10), atol=3)


def test_depth_at_lower_resolution_is_registered(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = write_scannet(rgbd_scene, tmp_path, depth_half=True)
    frame = read_capture(root).frames[0]
    assert frame.depth.shape == (12, 16)
    np.testing.assert_allclose(frame.depth[::2, ::2], rgbd_scene.depth[0][::2, ::2], atol=1e-6)
    np.testing.assert_allclose(frame.depth[1::2, 1::2], rgbd_scene.depth[0][::2, ::2], atol=1e-6)


def test_depth_at_lower_resolution_without_depth_intrinsics(rgbd_scene: RgbdScene, tmp_path):
    root = write_scannet(rgbd_scene, tmp_path, depth_half=True)
    (root / "intrinsic" / "intrinsic_depth.txt").unlink()
    frame = read_capture(root).frames[0]
    np.testing.assert_allclose(frame.depth[::2, ::2], rgbd_scene.depth[0][::2, ::2], atol=1e-6)


def test_inf_pose_is_skipped_with_warning(rgbd_scene: RgbdScene, tmp_path: Path, caplog) -> None:
    root = write_scannet(rgbd_scene, tmp_path)
    np.savetxt(root / "pose" / "2.txt", np.full((4, 4), -np.inf))
    with caplog.at_level(logging.WARNING, logger="dcseg.io.captures"):
        capture = read_capture(root)
    assert capture.names == ("0", "1", "3")
    assert "pose/2.txt" in caplog.text and "inf or NaN" in caplog.text


def test_stride_applies_after_skipping(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = write_scannet(rgbd_scene, tmp_path)
    np.savetxt(root / "pose" / "0.txt", np.full((4, 4), np.nan))
    assert read_capture(root, CaptureOptions(stride=2)).names == ("1", "3")


def test_every_problem_is_listed(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = write_scannet(rgbd_scene, tmp_path)
    (root / "depth" / "3.png").unlink()
    (root / "pose" / "1.txt").unlink()
    (root / "color" / "2.png").write_bytes(b"\x89PNG garbage")
    pose = rgbd_scene.c2w[0].copy()
    pose[:3, :3] *= 2.0
    np.savetxt(root / "pose" / "0.txt", pose)
    with pytest.raises(InputError) as info:
        read_capture(root)
    messages = sorted(str(p) for p in info.value.problems)
    assert messages == sorted(
        [
            "depth/3.png: missing (colour color/3.png has no depth)",
            "pose/1.txt: missing (colour color/1.png has no pose)",
            "color/2.png: cannot decode image (corrupt or not an image)",
            "pose/0.txt: pose is not a rigid transform (rotation not orthonormal, error 3)",
        ]
    )


def test_bad_pose_file_and_intrinsics(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = write_scannet(rgbd_scene, tmp_path)
    (root / "pose" / "1.txt").write_text("1 0 0\n0 1 0\n")
    with pytest.raises(InputError, match=r"pose/1\.txt: expected a 4x4 matrix, got 2 rows of 3"):
        read_capture(root)
    (root / "intrinsic" / "intrinsic_color.txt").unlink()
    with pytest.raises(InputError, match=r"intrinsic/intrinsic_color\.txt: missing"):
        read_capture(root)


def test_grey_and_16bit_colour(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = write_scannet(rgbd_scene, tmp_path)
    write_image(root / "color" / "0.png", rgbd_scene.rgb[0][:, :, 0])
    assert read_capture(root).frames[0].rgb.shape == (12, 16, 3)
    write_image(root / "color" / "1.png", np.zeros((12, 16, 3), np.uint16))
    with pytest.raises(InputError, match=r"color/1\.png: colour must be 8-bit, got uint16"):
        read_capture(root)
