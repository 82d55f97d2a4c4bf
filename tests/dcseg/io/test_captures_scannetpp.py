"""ScanNet++ iPhone layout: fixtures as the ScanNet++ toolkit leaves them after extracting the
frames (``iphone/rgb/frame_NNNNNN.jpg``, ``iphone/depth/frame_NNNNNN.png``) next to
``pose_intrinsic_imu.json`` (per frame: ``intrinsic`` 3x3, ``aligned_pose`` 4x4 c2w)."""

from __future__ import annotations

import json
from functools import partial
from pathlib import Path

import pytest

from dcseg.errors import InputError
from dcseg.io.captures import detect_layout, read_capture
from dcseg.io.images import write_image
from tests.dcseg.io.archived import check_zip_with_options
from tests.dcseg.io.layouts import (
    RgbdScene,
    assert_same_frames,
    check_synth_round_trip,
    check_validate_names_layout,
    mm,
    scene_capture,
)


def write_scannetpp(scene: RgbdScene, root: Path, every: int = 10, half_depth: bool = True) -> Path:
    """The scene folder with ``iphone/``: every ``every``-th frame extracted, depth at half the
    colour resolution (the LiDAR's is lower), a raw ``pose`` far from ``aligned_pose``."""
    iphone = root / "iphone"
    doc = {}
    for i in range(scene.n):
        name = f"frame_{i * every:06d}"
        write_image(iphone / "rgb" / f"{name}.png", scene.rgb[i])
        depth = mm(scene.depth[i])
        write_image(iphone / "depth" / f"{name}.png", depth[::2, ::2] if half_depth else depth)
        doc[name] = {
            "timestamp": i / 6.0,
            "intrinsic": scene.k.matrix().tolist(),
            "pose": (scene.c2w[i] + 50.0).tolist(),
            "aligned_pose": scene.c2w[i].tolist(),
            "imu": {"gravity": [0.0, -9.8, 0.0]},
        }
    doc["frame_099999"] = doc["frame_000000"]  # not extracted: not read
    (iphone / "pose_intrinsic_imu.json").write_text(json.dumps(doc))
    return root


def test_round_trip(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = write_scannetpp(rgbd_scene, tmp_path, half_depth=False)
    assert detect_layout(root) == "scannetpp"
    capture = read_capture(root)
    assert capture.layout == "scannetpp"
    assert capture.names == ("frame_000000", "frame_000010", "frame_000020", "frame_000030")
    assert_same_frames(capture.frames, scene_capture(rgbd_scene).frames, pose_atol=1e-12)
    assert capture.frames[1].files["pose"] == (
        "iphone/pose_intrinsic_imu.json:frame_000010.aligned_pose"
    )
    assert detect_layout(root / "iphone") == "scannetpp"


def test_lidar_depth_is_resampled(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    frame = read_capture(write_scannetpp(rgbd_scene, tmp_path)).frames[2]
    assert frame.depth.shape == (12, 16)
    assert frame.depth[5, 7] == pytest.approx(rgbd_scene.depth[2][4, 6])


def test_malformed_entries(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = write_scannetpp(rgbd_scene, tmp_path)
    path = root / "iphone" / "pose_intrinsic_imu.json"
    doc = json.loads(path.read_text())
    del doc["frame_000010"]
    doc["frame_000020"]["aligned_pose"] = [[1, 0, 0], [0, 1, 0]]
    doc["frame_000030"]["intrinsic"] = [[20, 0, 7.5], [0, 22, 5.5]]
    del doc["frame_000000"]["intrinsic"]
    path.write_text(json.dumps(doc))
    with pytest.raises(InputError) as info:
        read_capture(root)
    assert [str(p) for p in info.value.problems] == [
        "iphone/pose_intrinsic_imu.json: frame_000000.intrinsic: missing",
        "iphone/pose_intrinsic_imu.json: frame_000010: missing (colour rgb/frame_000010.png "
        "has no entry)",
        "iphone/pose_intrinsic_imu.json: frame_000020.aligned_pose: must be a 4x4 array of "
        "numbers (rows of 4)",
        "iphone/pose_intrinsic_imu.json: frame_000030.intrinsic: must be a 3x3 array of finite "
        "numbers (rows of 3)",
    ]
    path.write_text("[1, 2]")
    with pytest.raises(InputError, match=r"pose_intrinsic_imu\.json: must be an object"):
        read_capture(root)


def test_missing_depth(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = write_scannetpp(rgbd_scene, tmp_path)
    (root / "iphone" / "depth" / "frame_000020.png").unlink()
    with pytest.raises(InputError) as info:
        read_capture(root)
    assert [str(p) for p in info.value.problems] == [
        "iphone/depth/frame_000020.png: missing (colour iphone/rgb/frame_000020.png has no depth)"
    ]


def test_zip_with_options(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = write_scannetpp(rgbd_scene, tmp_path / "cap", half_depth=False)
    check_zip_with_options(rgbd_scene, root, "scannetpp")


def test_validate_names_the_layout(tmp_path: Path) -> None:
    check_validate_names_layout(tmp_path, write_scannetpp, "scannetpp")


def test_synth_scene_as_scannetpp(tmp_path: Path) -> None:
    """A ``dcseg synth`` capture written as ScanNet++ iPhone reads back the same."""
    check_synth_round_trip(tmp_path, partial(write_scannetpp, half_depth=False), pose_atol=1e-12)
