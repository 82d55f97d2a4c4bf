"""nerfstudio ``transforms.json`` layout."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from dcseg.errors import InputError
from dcseg.io.captures import detect_layout, read_capture
from dcseg.types import Lens
from tests.dcseg.io.layouts import (
    GL,
    RgbdScene,
    assert_same_frames,
    nerfstudio_doc,
    scene_capture,
    write_nerfstudio,
)


def _project_opencv(c2w: np.ndarray, k: np.ndarray, point: np.ndarray) -> np.ndarray:
    cam = np.linalg.inv(c2w) @ np.append(point, 1.0)
    assert cam[2] > 0, "point must be in front of the camera (OpenCV: +z forward)"
    uvw = k @ cam[:3]
    return np.asarray(uvw[:2] / uvw[2])


def _project_opengl(c2w_gl: np.ndarray, k: np.ndarray, point: np.ndarray) -> np.ndarray:
    x, y, z = (np.linalg.inv(c2w_gl) @ np.append(point, 1.0))[:3]
    assert z < 0, "point must be in front of the camera (OpenGL: -z forward)"
    return np.array([k[0, 0] * x / -z + k[0, 2], -k[1, 1] * y / -z + k[1, 2]])


def test_smoke(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = write_nerfstudio(rgbd_scene, tmp_path)
    assert detect_layout(root) == "nerfstudio"
    capture = read_capture(root)
    assert capture.names == tuple(f"frame_{i:05d}" for i in range(4))
    assert_same_frames(capture.frames, scene_capture(rgbd_scene).frames, pose_atol=1e-12)


def test_pose_conversion_projects_like_opengl(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    doc = nerfstudio_doc(rgbd_scene)
    gl = np.array(doc["frames"][0]["transform_matrix"])  # type: ignore[index]
    root = write_nerfstudio(rgbd_scene, tmp_path, doc)
    frame = read_capture(root).frames[0]
    k = frame.intrinsics.matrix()
    # a world point seen by frame 0 at pixel (4, 3) at 2 m depth (OpenCV axes)
    ray = np.linalg.inv(k) @ np.array([4.0, 3.0, 1.0]) * 2.0
    point = (rgbd_scene.c2w[0] @ np.append(ray, 1.0))[:3]
    np.testing.assert_allclose(_project_opencv(frame.c2w, k, point), [4.0, 3.0], atol=1e-9)
    np.testing.assert_allclose(_project_opengl(gl, k, point), [4.0, 3.0], atol=1e-9)
    np.testing.assert_allclose(frame.c2w, gl @ GL)


def test_depth_unit_and_per_frame_camera(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    doc = nerfstudio_doc(rgbd_scene)
    doc["depth_unit_scale_factor"] = 0.002
    doc["applied_transform"] = np.eye(4)[:3].tolist()
    frames = doc["frames"]
    frames[1].update(fl_x=30.0, cx=8.0)  # type: ignore[index]
    for key in ("w", "h"):
        doc.pop(key)
    capture = read_capture(write_nerfstudio(rgbd_scene, tmp_path, doc))
    np.testing.assert_allclose(capture.frames[0].depth, rgbd_scene.depth[0] * 2, atol=1e-6)
    k1 = capture.frames[1].intrinsics
    assert (k1.fx, k1.fy, k1.cx, k1.cy, k1.width) == (30.0, 22.0, 8.0, 5.5, 16)


def test_distortion_is_removed(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    """``k1 k2 k3 p1 p2`` (OPENCV) are OpenCV's ``k1 k2 p1 p2 k3``; per-frame values win; the
    frames are resampled onto the pinhole camera recorded with them."""
    doc = nerfstudio_doc(rgbd_scene)
    doc.update(k1=-0.1, k2=0.02, k3=0.001, p1=0.002, p2=-0.001)
    doc["frames"][1].update(camera_model="OPENCV_FISHEYE", k1=0.05, k3=0.0, p1=0, p2=0)  # type: ignore[index]
    capture = read_capture(write_nerfstudio(rgbd_scene, tmp_path, doc))
    first, second = (capture.frames[i].undistortion for i in (0, 1))
    assert first is not None and second is not None
    assert first.lens == Lens("opencv", (-0.1, 0.02, 0.002, -0.001, 0.001), first.lens.source)
    assert first.lens.source == "transforms.json:camera_model OPENCV"
    assert second.lens.coefficients == (0.05, 0.02, 0.0, 0.0)
    assert second.lens.model == "fisheye"
    assert capture.frames[0].intrinsics == first.pinhole != first.source
    assert first.source == rgbd_scene.k


@pytest.mark.parametrize(
    ("fields", "reason"),
    [
        ({"k4": 0.01}, "camera_model: k4 (nerfstudio's r^8 term) has no OpenCV equivalent"),
        ({"camera_model": "OPENCV_FISHEYE", "p1": 0.01}, "camera_model: a fisheye camera has no"),
        ({"camera_model": "EQUIRECTANGULAR"}, "camera_model: EQUIRECTANGULAR is not supported"),
    ],
)
def test_lens_it_cannot_model_is_refused_once(
    rgbd_scene: RgbdScene, tmp_path: Path, fields: dict[str, object], reason: str
) -> None:
    doc = nerfstudio_doc(rgbd_scene)
    doc.update(fields)
    with pytest.raises(InputError) as info:
        read_capture(write_nerfstudio(rgbd_scene, tmp_path, doc))
    shown = [str(p) for p in info.value.problems]
    assert len(shown) == 1 and shown[0].startswith(f"transforms.json: {reason}")


def test_missing_depth_path_and_camera(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    doc = nerfstudio_doc(rgbd_scene)
    doc.pop("fl_x")
    frames = doc["frames"]
    frames[2].pop("depth_file_path")  # type: ignore[index]
    frames[3]["transform_matrix"] = "identity"  # type: ignore[index]
    with pytest.raises(InputError) as info:
        read_capture(write_nerfstudio(rgbd_scene, tmp_path, doc))
    messages = [str(p) for p in info.value.problems]
    assert (
        "transforms.json: frames[2].depth_file_path: missing (dcseg needs depth for every frame)"
        in messages
    )
    assert (
        "transforms.json: frames[3].transform_matrix: must be a 4x4 array of numbers "
        "(rows of 4)" in messages
    )
    assert (
        "transforms.json: frames[0].fl_x: missing (neither in the frame nor at the top level)"
        in messages
    )


def test_missing_files_and_size_mismatch(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    doc = nerfstudio_doc(rgbd_scene)
    doc["w"] = 20
    root = write_nerfstudio(rgbd_scene, tmp_path, doc)
    (root / "depth" / "frame_00001.png").unlink()
    (root / "images" / "frame_00003.png").unlink()
    with pytest.raises(InputError) as info:
        read_capture(root)
    messages = [str(p) for p in info.value.problems]
    assert messages[:2] == [
        "depth/frame_00001.png: missing (colour images/frame_00001.png has no depth)",
        "images/frame_00003.png: missing (colour images/frame_00003.png has no colour)",
    ]
    assert (
        "transforms.json:frames[0]: intrinsics are for 20x12 but the image "
        "images/frame_00000.png is 16x12" in messages
    )


def test_invalid_json(tmp_path: Path) -> None:
    (tmp_path / "transforms.json").write_text(json.dumps([1, 2]))
    with pytest.raises(InputError, match=r"transforms\.json: must be an object, got an array"):
        read_capture(tmp_path)
