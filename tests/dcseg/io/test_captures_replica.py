"""NICE-SLAM Replica layout, including the real 60-frame sample when it is present."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from dcseg.config import CaptureOptions
from dcseg.errors import InputError
from dcseg.io.captures import detect_layout, read_capture
from dcseg.types import Intrinsics
from tests.dcseg.io.layouts import RgbdScene, assert_same_frames, scene_capture, write_replica

SAMPLE = Path("/work/shared/data/replica_room0_small")


def test_smoke(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = write_replica(rgbd_scene, tmp_path)
    assert detect_layout(root) == "replica"
    capture = read_capture(root)
    assert capture.names == tuple(f"frame{i:06d}" for i in range(4))
    assert_same_frames(
        capture.frames, scene_capture(rgbd_scene).frames, pose_atol=1e-12, depth_atol=1e-4
    )
    for i, frame in enumerate(capture.frames):
        assert frame.files["pose"] == f"traj.txt:line {i + 1}"


def test_cam_params_scale(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = write_replica(rgbd_scene, tmp_path)
    doc = json.loads((root / "cam_params.json").read_text())
    doc["camera"]["scale"] = 6553.5 * 2
    (root / "cam_params.json").write_text(json.dumps(doc))
    depth = read_capture(root).frames[0].depth
    np.testing.assert_allclose(depth, rgbd_scene.depth[0] / 2, atol=1e-4)


def test_intrinsics_from_options(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = write_replica(rgbd_scene, tmp_path, cam_params=False)
    with pytest.raises(InputError, match=r"no intrinsics: .*cam_params\.json.*CaptureOptions"):
        read_capture(root)
    options = CaptureOptions(intrinsics=(20.0, 22.0, 7.5, 5.5), size=(8, 6))
    frame = read_capture(root, options).frames[0]
    assert frame.intrinsics == rgbd_scene.k.scaled(8, 6)
    assert frame.files["intrinsics"] == "CaptureOptions.intrinsics"


def test_cam_params_size_mismatch(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = write_replica(rgbd_scene, tmp_path)
    doc = json.loads((root / "cam_params.json").read_text())
    doc["camera"]["w"] = 32
    (root / "cam_params.json").write_text(json.dumps(doc))
    with pytest.raises(InputError, match=r"cam_params\.json:camera: intrinsics are for 32x12"):
        read_capture(root)


def test_bad_cam_params(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = write_replica(rgbd_scene, tmp_path)
    (root / "cam_params.json").write_text(json.dumps({"camera": {"w": 16}}))
    with pytest.raises(InputError) as info:
        read_capture(root)
    assert "cam_params.json: camera.fx: missing" in str(info.value)
    assert "camera.h: missing" in str(info.value)


def test_trajectory_too_short_and_malformed(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = write_replica(rgbd_scene, tmp_path, extra_rows=0)
    lines = (root / "traj.txt").read_text().splitlines()
    lines[1] = "1 2 3"
    (root / "traj.txt").write_text("\n".join(lines[:3]) + "\n")
    with pytest.raises(InputError) as info:
        read_capture(root)
    assert [str(p) for p in info.value.problems] == [
        "traj.txt:line 2: expected 16 numbers (a row-major 4x4 pose)",
        "traj.txt: has 3 poses but frame 3 needs line 4",
    ]


def test_missing_depth(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = write_replica(rgbd_scene, tmp_path)
    (root / "results" / "depth000002.png").unlink()
    with pytest.raises(
        InputError,
        match=r"results/depth000002\.png: missing \(colour results/frame000002\.png has no depth\)",
    ):
        read_capture(root)


def test_real_sample() -> None:
    if not (SAMPLE / "traj.txt").is_file():
        pytest.skip(f"Replica sample not found at {SAMPLE}")
    options = CaptureOptions(size=(300, 170), max_frames=5, intrinsics=(600.0, 600.0, 599.5, 339.5))
    capture = read_capture(SAMPLE, options)
    assert capture.layout == "replica"
    assert capture.names == tuple(f"frame{i:06d}" for i in range(5))
    frame = capture.frames[0]
    assert frame.rgb.shape == (170, 300, 3)
    assert frame.intrinsics == Intrinsics(600.0, 600.0, 599.5, 339.5, 1200, 680).scaled(300, 170)
    valid = frame.depth[frame.depth > 0]
    assert valid.size > 0.9 * frame.depth.size
    assert 0.3 < float(np.median(valid)) < 10.0
    np.testing.assert_allclose(frame.c2w[3], [0, 0, 0, 1])
