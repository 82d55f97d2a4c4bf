"""Stray Scanner layout: fixtures written as the app writes them (``docs/format.md`` of
strayrobots/scanner; poses as its ``OdometryEncoder.swift`` makes them from ARKit's camera
transform: ``q = q_WA * q_AC``, ``q_AC`` a half-turn about x), colour as ``rgb.mp4``
(OpenCV's mp4v encoder) or an ``rgb/`` folder of images."""

from __future__ import annotations

import logging
from pathlib import Path

import cv2
import numpy as np
import pytest
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from dcseg.config import CaptureOptions
from dcseg.errors import InputError
from dcseg.io import video
from dcseg.io.captures import detect_layout, read_capture, read_planned
from dcseg.io.images import write_image
from dcseg.types import Intrinsics
from tests.dcseg.io.archived import check_zip_with_options
from tests.dcseg.io.layouts import (
    GL,
    RgbdScene,
    assert_same_frames,
    check_synth_round_trip,
    check_validate_names_layout,
    mm,
    scene_capture,
)

HEADER = "timestamp, frame, x, y, z, qx, qy, qz, qw"
Q_AC = Rotation.from_quat([1.0, 0.0, 0.0, 0.0])
"""The app's ``simd_quatf(ix: 1, iy: 0, iz: 0, r: 0)``: a half-turn about the camera's x."""


def odometry_line(i: int, c2w: NDArray[np.float64]) -> str:
    """Frame ``i``'s row as the app writes it from ARKit's camera transform (OpenGL axes)."""
    arkit = c2w @ GL  # the camera transform ARKit reports for this camera
    q = (Rotation.from_matrix(arkit[:3, :3]) * Q_AC).as_quat()  # q_WA * q_AC, scalar last
    values = [f"{0.1 * i + 100:.6f}", f"{i:06d}", *(f"{v:.17g}" for v in (*arkit[:3, 3], *q))]
    return ", ".join(values)


def camera_matrix(k: Intrinsics) -> str:
    rows = [(k.fx, 0.0, k.cx), (0.0, k.fy, k.cy), (0.0, 0.0, 1.0)]
    return "\n".join(", ".join(f"{v:.17g}" for v in row) for row in rows) + "\n"


def write_stray(
    scene: RgbdScene, root: Path, *, video: bool = False, depth_factor: int = 1
) -> Path:
    """A recording: colour as ``rgb/NNNNNN.png`` (exact) or ``rgb.mp4``; depth in mm at the
    colour size / ``depth_factor``; confidence 2 except the first row (0)."""
    for i in range(scene.n):
        name = f"{i:06d}"
        if not video:
            write_image(root / "rgb" / f"{name}.png", scene.rgb[i])
        depth = mm(scene.depth[i])[::depth_factor, ::depth_factor]
        write_image(root / "depth" / f"{name}.png", depth)
        confidence = np.full(depth.shape, 2, np.uint8)
        confidence[0] = 0
        write_image(root / "confidence" / f"{name}.png", confidence)
    if video:
        write_video(root / "rgb.mp4", scene.rgb)
    lines = [HEADER, *(odometry_line(i, scene.c2w[i]) for i in range(scene.n))]
    (root / "odometry.csv").write_text("\n".join(lines) + "\n")
    (root / "camera_matrix.csv").write_text(camera_matrix(scene.k))
    (root / "imu.csv").write_text("timestamp, a_x, a_y, a_z, alpha_x, alpha_y, alpha_z\n")
    return root


def write_video(path: Path, frames: list[NDArray[np.uint8]]) -> None:
    height, width = frames[0].shape[:2]
    path.parent.mkdir(parents=True, exist_ok=True)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter.fourcc(*"mp4v"), 30.0, (width, height))
    if not writer.isOpened():
        pytest.skip("OpenCV cannot write mp4v here")
    for frame in frames:
        writer.write(np.ascontiguousarray(frame[:, :, ::-1]))
    writer.release()


def flat_scene(n: int = 5, width: int = 64, height: int = 48) -> RgbdScene:
    """Frames of one distinct colour each (a lossy video keeps them apart), random poses."""
    rng = np.random.default_rng(3)
    rgb = [np.full((height, width, 3), (40 * i + 20, 200 - 30 * i, 90), np.uint8) for i in range(n)]
    depth = [np.full((height, width), 1.5 + 0.25 * i, np.float32) for i in range(n)]
    c2w = []
    for _ in range(n):
        pose = np.eye(4)
        pose[:3, :3] = cv2.Rodrigues(rng.normal(size=3))[0]
        pose[:3, 3] = rng.normal(size=3)
        c2w.append(pose)
    return RgbdScene(rgb, depth, c2w, Intrinsics(50.0, 52.0, 31.5, 23.5, width, height))


def test_round_trip_with_images(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = write_stray(rgbd_scene, tmp_path)
    assert detect_layout(root) == "stray"
    capture = read_capture(root)
    assert capture.layout == "stray" and capture.names == tuple(f"{i:06d}" for i in range(4))
    assert_same_frames(capture.frames, scene_capture(rgbd_scene).frames, pose_atol=1e-9)
    files = capture.frames[2].files
    assert files["pose"] == "odometry.csv:line 4" and files["rgb"] == "rgb/000002.png"
    assert files["intrinsics"] == "camera_matrix.csv"


def test_video_frames_follow_the_odometry_rows(tmp_path: Path) -> None:
    scene = flat_scene()
    root = write_stray(scene, tmp_path, video=True)
    assert detect_layout(root) == "stray"
    capture = read_capture(root)
    assert len(capture) == 5 and capture.frames[0].intrinsics == scene.k
    for frame, rgb in zip(capture.frames, scene.rgb, strict=True):
        assert np.abs(frame.rgb.astype(int) - rgb.astype(int)).mean() < 6  # mp4v is lossy
    assert capture.frames[3].files["rgb"] == "rgb.mp4#3"
    assert not video.open_videos(root)  # released when the listing's block ends
    for options in (CaptureOptions(stride=2), CaptureOptions(stride=3, max_frames=2)):
        strided = read_capture(root, options)  # skips forward in the open video
        for frame in strided.frames:
            i = int(frame.name)
            assert np.abs(frame.rgb.astype(int) - scene.rgb[i].astype(int)).mean() < 6
            np.testing.assert_allclose(frame.c2w, scene.c2w[i], atol=1e-9)


def test_planned_reading_takes_the_size_from_the_video(tmp_path: Path) -> None:
    scene = flat_scene()
    root = write_stray(scene, tmp_path, video=True)
    capture, plan = read_planned(root, CaptureOptions(size=(32, 24)))
    assert plan.size == (32, 24) and len(capture) == 5
    assert capture.frames[4].intrinsics == scene.k.scaled(32, 24)
    assert np.abs(capture.frames[4].rgb.astype(int) - scene.rgb[4][::2, ::2]).mean() < 6


def test_images_smaller_than_the_video_scale_the_camera_matrix(tmp_path: Path) -> None:
    """``camera_matrix.csv`` is stated for the video's 64x48; ``rgb/`` images at 32x24 take it
    scaled with the pixel-centre convention (``docs/conventions.md``)."""
    scene = flat_scene(n=2)
    root = write_stray(scene, tmp_path, video=True)
    for i in range(2):
        write_image(root / "rgb" / f"{i:06d}.png", scene.rgb[i][::2, ::2])
    frame = read_capture(root).frames[1]
    assert frame.files["rgb"] == "rgb/000001.png"
    assert frame.intrinsics == Intrinsics(25.0, 26.0, 15.5, 11.5, 32, 24)
    write_image(root / "rgb" / "000000.png", scene.rgb[0][:20])
    assert problems(root) == [
        "rgb/000000.png: 64x20 images have another aspect ratio than the video's 64x48, "
        "which camera_matrix.csv is stated for"
    ]


def test_a_video_shorter_than_the_odometry_drops_the_last_rows(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    scene = flat_scene()
    root = write_stray(scene, tmp_path, video=True)
    write_video(root / "rgb.mp4", scene.rgb[:3])
    with caplog.at_level(logging.WARNING):
        capture = read_capture(root)
    assert capture.names == ("000000", "000001", "000002")
    assert "rgb.mp4 has 3 frames for 5 odometry rows; frames from 000003 on are dropped" in (
        caplog.text
    )


def test_a_known_point_projects_where_the_app_saw_it(tmp_path: Path) -> None:
    """A world point, seen by each camera as ARKit does (camera looking down -z, y up): its
    pixel is marked in the colour image and its depth written at the depth resolution
    (4x smaller, intrinsics scaled as StrayVisualizer scales them). Read back, dcseg's
    camera-to-world pose and intrinsics project the point onto the marked pixel, and the
    depth there is the point's distance along the optical axis."""
    scene = flat_scene(n=3)
    point = np.array([0.3, -0.2, 0.5])
    k = scene.k
    marked = []
    for i in range(scene.n):
        c2w = np.eye(4)
        c2w[:3, :3] = Rotation.from_euler("xyz", [10 * i, 15 * i - 20, 5]).as_matrix()
        seen = np.array([0.1 * i - 0.1, 0.05 * i, 1.0 + 0.5 * i])  # where the camera sees it
        c2w[:3, 3] = point - c2w[:3, :3] @ seen
        scene.c2w[i][:] = c2w
        arkit = c2w @ GL  # the camera transform ARKit reports
        x, y, z = (np.linalg.inv(arkit) @ np.append(point, 1.0))[:3]
        # ARKit's camera looks down -z with y up: pixel = (fx x / -z + cx, fy (-y) / -z + cy)
        u, v = k.fx * x / -z + k.cx, k.fy * -y / -z + k.cy
        col, row = int(round(u)), int(round(v))
        assert 4 <= col < k.width - 4 and 4 <= row < k.height - 4
        scene.rgb[i][row, col] = (255, 255, 255)
        scene.depth[i][:] = np.round(-z, 3)  # a plane facing the camera through the point
        marked.append((col, row, u, v, -z))
    root = write_stray(scene, tmp_path, depth_factor=4)
    capture = read_capture(root)
    for frame, (col, row, u, v, depth) in zip(capture.frames, marked, strict=True):
        camera = np.linalg.inv(frame.c2w) @ np.append(point, 1.0)
        pixel = frame.intrinsics.matrix() @ camera[:3]
        assert camera[2] == pytest.approx(depth)  # in front, at the written depth
        np.testing.assert_allclose(pixel[:2] / pixel[2], (u, v), atol=1e-9)
        assert tuple(np.argwhere(frame.rgb.sum(axis=2) == 765)[0]) == (row, col)
        assert frame.depth[row, col] == pytest.approx(depth, abs=5e-4)


def test_min_confidence_drops_low_confidence_depth(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = write_stray(rgbd_scene, tmp_path)
    kept = read_capture(root).frames[1]
    filtered = read_capture(root, CaptureOptions(min_confidence=1)).frames[1]
    assert (filtered.depth[0] == 0).all() and np.array_equal(filtered.depth[1:], kept.depth[1:])
    assert filtered.files["confidence"] == "confidence/000001.png"


def test_older_recordings_headerless_odometry_and_npy_depth(
    rgbd_scene: RgbdScene, tmp_path: Path
) -> None:
    """Early app versions: ``x, y, z, qx, qy, qz, qw`` rows without a header, and depth as
    ``.npy`` millimetres (StrayVisualizer's ``load_depth``)."""
    root = write_stray(rgbd_scene, tmp_path)
    rows = (root / "odometry.csv").read_text().splitlines()[1:]
    (root / "odometry.csv").write_text("\n".join(r.split(", ", 2)[2] for r in rows) + "\n")
    for i in range(rgbd_scene.n):
        (root / "depth" / f"{i:06d}.png").unlink()
        np.save(root / "depth" / f"{i:06d}.npy", mm(rgbd_scene.depth[i]))
    capture = read_capture(root)
    assert_same_frames(capture.frames, scene_capture(rgbd_scene).frames, pose_atol=1e-9)
    assert capture.frames[0].files["pose"] == "odometry.csv:line 1"


def problems(root: Path) -> list[str]:
    with pytest.raises(InputError) as info:
        read_capture(root)
    return [str(p) for p in info.value.problems]


def test_malformed_files_are_named(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = write_stray(rgbd_scene, tmp_path)
    odometry = root / "odometry.csv"
    lines = odometry.read_text().splitlines()
    bad = [
        lines[0],
        lines[1].rsplit(",", 1)[0],
        lines[2],
        lines[3].replace(", 000002,", ", 000001,"),
    ]
    odometry.write_text("\n".join([*bad, lines[4]]) + "\n")
    assert problems(root) == [
        "odometry.csv:line 2: expected 9 values (timestamp, frame, x, y, z, qx, qy, qz, qw), got 8",
        "odometry.csv:line 4: frame 000001 appears again (first on line 3)",
    ]
    values = lines[1].split(", ")
    values[-1] = "2.0"
    odometry.write_text("\n".join([lines[0], ", ".join(values)]) + "\n")
    assert problems(root) == [
        "odometry.csv:line 2: quaternion (qx, qy, qz, qw) has norm "
        f"{np.linalg.norm([float(v) for v in values[-4:]]):.6g}, expected 1"
    ]
    odometry.write_text("timestamp, frame, x, y, z, qx, qy, qz\n" + "\n".join(lines[1:]))
    assert problems(root) == [
        "odometry.csv:line 1: header 'timestamp, frame, x, y, z, qx, qy, qz' lacks column(s) qw"
    ]
    odometry.write_text("\n".join(lines) + "\n")
    (root / "camera_matrix.csv").write_text("500, 0, 320\n0, 500, 240\n")
    assert problems(root) == [
        "camera_matrix.csv: expected a 3x3 matrix of finite numbers, "
        "got [[500.0, 0.0, 320.0], [0.0, 500.0, 240.0]]"
    ]
    (root / "camera_matrix.csv").write_text(camera_matrix(rgbd_scene.k))
    (root / "depth" / "000003.png").unlink()
    assert problems(root) == ["depth/000003.png: missing (colour rgb/000003.png has no depth)"]


def test_a_corrupt_video_and_a_missing_depth_are_named(tmp_path: Path) -> None:
    root = write_stray(flat_scene(n=2), tmp_path, video=True)
    (root / "depth" / "000001.png").unlink()
    assert problems(root) == [
        "depth/000001.png: missing (frame 1 of rgb.mp4, odometry.csv:line 3, has no depth)"
    ]
    (root / "rgb.mp4").write_bytes(b"not a video at all")
    assert problems(root) == ["rgb.mp4: cannot open video (corrupt, or a codec FFmpeg lacks)"]


def test_zip_with_options(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = write_stray(rgbd_scene, tmp_path / "cap")
    check_zip_with_options(rgbd_scene, root, "stray")


def test_validate_names_the_layout(tmp_path: Path) -> None:
    check_validate_names_layout(tmp_path, write_stray, "stray")


def test_validate_names_the_layout_of_a_video_recording(tmp_path: Path) -> None:
    check_validate_names_layout(
        tmp_path, lambda s, r: write_stray(flat_scene(n=2), r, video=True), "stray"
    )


def test_synth_scene_as_stray(tmp_path: Path) -> None:
    """A ``dcseg synth`` capture written as a Stray recording (images) reads back the same."""
    check_synth_round_trip(tmp_path, write_stray, pose_atol=1e-9)
