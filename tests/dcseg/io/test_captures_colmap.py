"""COLMAP sparse models: fixtures written per COLMAP's output format (doc/format.rst) and the
byte layout of its reference reader (scripts/python/read_write_model.py), with struct."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from dcseg.cli.validate import format_report
from dcseg.config import CaptureOptions
from dcseg.errors import InputError
from dcseg.inputs import RunInputs
from dcseg.io.captures import detect_layout, read_capture
from dcseg.io.captures.manifest import write_capture
from dcseg.io.images import write_image
from dcseg.io.validate import validate_inputs
from dcseg.types import Capture, Intrinsics, Lens
from tests.dcseg.io.archived import check_zip_with_options
from tests.dcseg.io.layouts import (
    RgbdScene,
    assert_same_frames,
    capture_scene,
    check_validate_names_layout,
    make_scene,
    mm,
    scene_capture,
    synth_capture,
)

MODEL_IDS = {"SIMPLE_PINHOLE": 0, "PINHOLE": 1, "SIMPLE_RADIAL": 2, "OPENCV": 4, "FOV": 7}
Cameras = dict[int, tuple[str, int, int, list[float]]]
ImageRow = tuple[int, list[float], list[float], int, str]  # id, qvec, tvec, camera id, name
TEXT_POINTS = {8: "12.5 3.25 -1 40.0 7.5 12", 10: "12.5 3.25 -1"}


def world_to_camera(c2w: np.ndarray) -> tuple[list[float], list[float]]:
    """COLMAP's ``QW QX QY QZ`` and ``TX TY TZ``: x_cam = R x_world + t."""
    rotation = c2w[:3, :3].T
    qx, qy, qz, qw = Rotation.from_matrix(rotation).as_quat()
    return [qw, qx, qy, qz], list(-rotation @ c2w[:3, 3])


def pinhole(k: Intrinsics) -> Cameras:
    """One PINHOLE camera; COLMAP's principal point is ours + 0.5 (pixel corner origin)."""
    return {1: ("PINHOLE", k.width, k.height, [k.fx, k.fy, k.cx + 0.5, k.cy + 0.5])}


def write_text_model(folder: Path, cameras: Cameras, images: list[ImageRow]) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    lines = ["# Camera list with one line of data per camera:", "#   CAMERA_ID, MODEL, ..."]
    for cid, (model, w, h, params) in cameras.items():
        lines.append(" ".join(str(v) for v in [cid, model, w, h, *params]))
    (folder / "cameras.txt").write_text("\n".join(lines) + "\n")
    lines = ["# Image list with two lines of data per image:", "#   IMAGE_ID, QW, ..."]
    for iid, q, t, cid, name in images:
        pose = " ".join(repr(float(v)) for v in (*q, *t))
        lines.append(f"{iid} {pose} {cid} {name}")
        lines.append(TEXT_POINTS.get(iid, ""))  # 2D points "X Y POINT3D_ID ...", maybe none
    (folder / "images.txt").write_text("\n".join(lines) + "\n")
    # POINT3D_ID X Y Z R G B ERROR TRACK[] as (IMAGE_ID, POINT2D_IDX): seen by image 8 only
    (folder / "points3D.txt").write_text("# 3D point list\n12 0.5 0.25 2.0 200 100 50 0.7 8 1\n")


def write_binary_model(folder: Path, cameras: Cameras, images: list[ImageRow]) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    out = struct.pack("<Q", len(cameras))
    for cid, (model, w, h, params) in cameras.items():
        out += struct.pack("<iiQQ", cid, MODEL_IDS[model], w, h)
        out += struct.pack("<" + "d" * len(params), *params)
    (folder / "cameras.bin").write_bytes(out)
    out = struct.pack("<Q", len(images))
    for iid, q, t, cid, name in images:
        out += struct.pack("<i7di", iid, *q, *t, cid) + name.encode("utf-8") + b"\x00"
        points = [(12.5, 3.25, -1), (40.0, 7.5, 12)][: iid % 3]
        out += struct.pack("<Q", len(points))
        out += b"".join(struct.pack("<ddq", *p) for p in points)
    (folder / "images.bin").write_bytes(out)
    # points3D: one point, for completeness of the model (not read)
    point = struct.pack("<QdddBBBd", 12, 0.5, 0.25, 2.0, 200, 100, 50, 0.7)
    track = struct.pack("<Q", 1) + struct.pack("<ii", 8, 1)  # image 8's second 2D point
    (folder / "points3D.bin").write_bytes(struct.pack("<Q", 1) + point + track)


def write_colmap(
    scene: RgbdScene, root: Path, binary: bool = True, cameras: Cameras | None = None
) -> Path:
    """Images in ``images/``, depth as uint16 mm PNG in ``depth/``; image ids deliberately not
    in name order (COLMAP's ids are unordered)."""
    images: list[ImageRow] = []
    for i in range(scene.n):
        write_image(root / "images" / f"frame_{i}.png", scene.rgb[i])
        write_image(root / "depth" / f"frame_{i}.png", mm(scene.depth[i]))
        q, t = world_to_camera(scene.c2w[i])
        images.append((10 - i, q, t, 1, f"frame_{i}.png"))
    writer = write_binary_model if binary else write_text_model
    writer(root / "sparse" / "0", cameras or pinhole(scene.k), images[::-1])
    return root


def check_round_trip(scene: RgbdScene, root: Path) -> None:
    capture = read_capture(root)
    assert capture.layout == "colmap"
    assert capture.names == tuple(f"frame_{i}" for i in range(scene.n))
    assert_same_frames(capture.frames, scene_capture(scene).frames, pose_atol=1e-9)


@pytest.mark.parametrize("binary", [True, False])
def test_round_trip(rgbd_scene: RgbdScene, tmp_path: Path, binary: bool) -> None:
    root = write_colmap(rgbd_scene, tmp_path, binary=binary)
    assert detect_layout(root) == "colmap"
    check_round_trip(rgbd_scene, root)
    frame = read_capture(root).frames[0]
    suffix = "bin" if binary else "txt"
    assert frame.files["intrinsics"].startswith(f"sparse/0/cameras.{suffix}")
    assert frame.files["pose"] == (
        "sparse/0/images.bin:image 10" if binary else "sparse/0/images.txt:line 9 (image 10)"
    )


def test_model_in_sparse_and_npy_depth(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = write_colmap(rgbd_scene, tmp_path)
    (root / "sparse" / "0").rename(root / "sparse_0")
    (root / "sparse").rmdir()
    (root / "sparse_0").rename(root / "sparse")
    (root / "depth" / "frame_1.png").unlink()
    np.save(root / "depth" / "frame_1.npy", rgbd_scene.depth[1])
    check_round_trip(rgbd_scene, root)


def test_single_focal_and_zero_distortion(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    k = Intrinsics(20.0, 20.0, 7.5, 5.5, 16, 12)
    scene = RgbdScene(rgbd_scene.rgb, rgbd_scene.depth, rgbd_scene.c2w, k)
    for model, extra in (("SIMPLE_PINHOLE", []), ("SIMPLE_RADIAL", [0.0])):
        cameras: Cameras = {1: (model, 16, 12, [20.0, 8.0, 6.0, *extra])}
        check_round_trip(scene, write_colmap(scene, tmp_path / model, cameras=cameras))
    opencv: Cameras = {1: ("OPENCV", 16, 12, [20.0, 20.0, 8.0, 6.0, 0.0, 0.0, 0.0, 0.0])}
    check_round_trip(scene, write_colmap(scene, tmp_path / "opencv", False, opencv))


def test_distortion_is_removed_when_read(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    """A distorted camera's frames come undistorted onto a pinhole camera of their size, with
    the lens recorded; depth is resampled by nearest neighbour (no value is made up)."""
    cameras: Cameras = {1: ("OPENCV", 16, 12, [20.0, 22.0, 8.0, 6.0, -0.1, 0.01, 0.001, 0.0])}
    root = write_colmap(rgbd_scene, tmp_path / "a", binary=False, cameras=cameras)
    capture = read_capture(root)
    for frame, depth in zip(capture.frames, rgbd_scene.depth, strict=True):
        u = frame.undistortion
        assert u is not None and frame.intrinsics == u.pinhole
        assert u.lens == Lens(
            "opencv", (-0.1, 0.01, 0.001, 0.0), "sparse/0/cameras.txt:line 3 (camera 1) (OPENCV)"
        )
        assert u.source == Intrinsics(20.0, 22.0, 7.5, 5.5, 16, 12)
        assert u.pinhole.fx < u.source.fx  # barrel distortion: a wider pinhole view
        assert frame.depth.shape == (12, 16) and np.isin(frame.depth, depth).all()
    report = format_report(validate_inputs(RunInputs(root)).summary, [])
    assert (
        "undistorted: 4 frame(s) through the opencv lens (-0.1 0.01 0.001 0) of "
        "sparse/0/cameras.txt:line 3 (camera 1) (OPENCV)" in report
    )


def test_fisheye_lens_and_zero_distortion(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    cameras: Cameras = {
        1: ("OPENCV_FISHEYE", 16, 12, [20.0, 22.0, 8.0, 6.0, 0.05, 0.0, 0.0, 0.0]),
        2: ("OPENCV", 16, 12, [20.0, 22.0, 8.0, 6.0, 0.0, 0.0, 0.0, 0.0]),
    }
    root = write_colmap(rgbd_scene, tmp_path, binary=False, cameras=cameras)
    folder = root / "sparse" / "0"
    text = (folder / "images.txt").read_text()
    (folder / "images.txt").write_text(text.replace(" 1 frame_1.png", " 2 frame_1.png"))
    frames = read_capture(root).frames
    assert [f.undistortion is None for f in frames] == [False, True, False, False]
    lens = frames[0].undistortion.lens  # type: ignore[union-attr]
    assert (lens.model, lens.coefficients) == ("fisheye", (0.05, 0.0, 0.0, 0.0))
    assert frames[1].intrinsics == Intrinsics(20.0, 22.0, 7.5, 5.5, 16, 12)


def test_camera_models_it_cannot_undistort_are_refused(
    rgbd_scene: RgbdScene, tmp_path: Path
) -> None:
    cameras: Cameras = {1: ("FOV", 16, 12, [20.0, 22.0, 8.0, 6.0, 0.9])}
    root = write_colmap(rgbd_scene, tmp_path / "b", cameras=cameras)
    with pytest.raises(InputError) as info:
        read_capture(root)
    assert str(info.value.problems[0]) == (
        "sparse/0/cameras.bin:camera 1: camera model FOV is not supported: dcseg reads the "
        "pinhole models and SIMPLE_RADIAL, RADIAL, OPENCV, FULL_OPENCV and OPENCV_FISHEYE "
        "(undistorting the images); undistort the images first with `colmap "
        "image_undistorter` or, without COLMAP, `pip install pycolmap` and "
        "`pycolmap.undistort_images(OUT, MODEL_FOLDER, IMAGES_FOLDER)` (both write PINHOLE "
        "cameras and undistorted images; segment those)"
    )


def test_unknown_camera_model(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = write_colmap(rgbd_scene, tmp_path / "t", binary=False)
    (root / "sparse" / "0" / "cameras.txt").write_text("# cameras\n1 PINHOLY 16 12 20 22 8 6\n")
    with pytest.raises(InputError) as info:
        read_capture(root)
    assert str(info.value).startswith(
        "sparse/0/cameras.txt:line 2: unknown camera model 'PINHOLY' (COLMAP's models are "
        "SIMPLE_PINHOLE, PINHOLE,"
    )
    root = write_colmap(rgbd_scene, tmp_path / "b")
    cameras = root / "sparse" / "0" / "cameras.bin"
    raw = bytearray(cameras.read_bytes())
    raw[12:16] = struct.pack("<i", 42)  # the model id of camera 1
    cameras.write_bytes(bytes(raw))
    with pytest.raises(InputError, match=r"^sparse/0/cameras\.bin: camera 1 \(id 1\): unknown "):
        read_capture(root)


def test_truncated_binary(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = write_colmap(rgbd_scene, tmp_path)
    images = root / "sparse" / "0" / "images.bin"
    raw = images.read_bytes()  # image 7 first: 64 bytes, "frame_3.png\0", 1 point of 24 bytes
    images.write_bytes(raw[:40])
    with pytest.raises(InputError) as info:
        read_capture(root)
    assert str(info.value) == (
        "sparse/0/images.bin: truncated: declares 4 images but only 32 bytes follow "
        "(each takes at least 73)"
    )
    one = struct.pack("<Q", 1)
    images.write_bytes(one + raw[8 : 8 + 64 + 12 + 8 + 10])
    with pytest.raises(InputError) as info:
        read_capture(root)
    assert str(info.value) == (
        "sparse/0/images.bin: truncated at byte 92: image 1 (id 7): 1 2D points needs 24 bytes, "
        "10 left"
    )
    images.write_bytes(one + raw[8 : 8 + 64 + 5] + b"x" * 10)
    with pytest.raises(InputError) as info:
        read_capture(root)
    assert str(info.value) == (
        "sparse/0/images.bin: truncated at byte 72: image 1 (id 7): name ends before its NUL "
        "terminator"
    )
    cameras = root / "sparse" / "0" / "cameras.bin"
    cameras.write_bytes(cameras.read_bytes()[:50])
    with pytest.raises(InputError) as info:
        read_capture(root)
    assert str(info.value) == (
        "sparse/0/cameras.bin: truncated at byte 32: camera 1 (id 1): PINHOLE parameters needs "
        "32 bytes, 18 left"
    )


def test_empty_image_name(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = write_colmap(rgbd_scene, tmp_path)
    q, t = world_to_camera(rgbd_scene.c2w[0])
    write_binary_model(root / "sparse" / "0", pinhole(rgbd_scene.k), [(5, q, t, 1, "")])
    with pytest.raises(InputError) as info:
        read_capture(root)
    assert [str(p) for p in info.value.problems] == ["sparse/0/images.bin:image 5: NAME is empty"]


def test_malformed_text(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = write_colmap(rgbd_scene, tmp_path, binary=False)
    path = root / "sparse" / "0" / "images.txt"
    lines = path.read_text().splitlines()
    lines[2] = " ".join(lines[2].split()[:9])  # no NAME
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError) as info:
        read_capture(root)
    assert str(info.value) == (
        "sparse/0/images.txt:line 3: expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME, "
        "got 9 values"
    )
    lines[2] = "7 1 0 0 0 0 0 x 1 frame_3.png"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=r"line 3: QW QX QY QZ TX TY TZ must be numbers"):
        read_capture(root)
    lines[2] = "7 0.5 0 0 0 0 0 0 3 frame_3.png"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError) as info:
        read_capture(root)
    assert [str(p) for p in info.value.problems] == [
        "sparse/0/images.txt:line 3 (image 7): CAMERA_ID 3: no such camera in the cameras file",
        "sparse/0/images.txt:line 3 (image 7): quaternion (QW, QX, QY, QZ) has norm 0.5, "
        "expected 1",
    ]
    (root / "sparse" / "0" / "cameras.txt").write_text("1 PINHOLE 16 12 20 22 8\n")
    with pytest.raises(InputError, match=r"cameras\.txt:line 1: PINHOLE has 4 parameters, got 3"):
        read_capture(root)


def test_missing_parts_and_size_mismatch(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = write_colmap(rgbd_scene, tmp_path)
    (root / "depth" / "frame_2.png").unlink()
    (root / "images" / "frame_0.png").unlink()
    with pytest.raises(InputError) as info:
        read_capture(root)
    assert [str(p) for p in info.value.problems] == [
        "images/frame_0.png: missing (colour images/frame_0.png has no colour)",
        "depth/frame_2.png: missing (colour images/frame_2.png has no depth)",
    ]
    cameras: Cameras = {1: ("PINHOLE", 32, 24, [20.0, 22.0, 8.0, 6.0])}
    root = write_colmap(rgbd_scene, tmp_path / "b", cameras=cameras)
    with pytest.raises(InputError, match=r"cameras\.bin:camera 1: intrinsics are for 32x24"):
        read_capture(root)


def test_depth_at_another_resolution_is_resampled(tmp_path: Path) -> None:
    scene = make_scene(n=2)
    root = write_colmap(scene, tmp_path)
    write_image(root / "depth" / "frame_1.png", mm(scene.depth[1])[::2, ::2])
    frame = read_capture(root).frames[1]
    assert frame.depth.shape == (12, 16)
    assert frame.depth[3, 5] == pytest.approx(scene.depth[1][2, 4])


def remove_depth(root: Path) -> Path:
    for path in (root / "depth").iterdir():
        path.unlink()
    (root / "depth").rmdir()
    return root


@pytest.mark.parametrize("binary", [True, False])
def test_rgb_only_model_reads_with_its_sparse_points(
    rgbd_scene: RgbdScene, tmp_path: Path, binary: bool
) -> None:
    """Without depth/ the capture is RGB-only: depth all 0, the points3D row read (xyz, rgb,
    error, track length), the images' colour and poses as with depth."""
    capture = read_capture(remove_depth(write_colmap(rgbd_scene, tmp_path, binary=binary)))
    assert capture.layout == "colmap" and capture.depth_source == "none"
    assert not capture.has_depth
    assert all(not f.depth.any() and f.depth.shape == f.rgb.shape[:2] for f in capture.frames)
    assert capture.frames[0].files["depth"] == "no depth (RGB-only)"
    expected = scene_capture(rgbd_scene).frames
    for frame, before in zip(capture.frames, expected, strict=True):
        np.testing.assert_array_equal(frame.rgb, before.rgb)
        np.testing.assert_allclose(frame.c2w, before.c2w, atol=1e-9)
    sparse = capture.sparse
    assert sparse is not None and len(sparse) == 1
    np.testing.assert_array_equal(sparse.xyz, [[0.5, 0.25, 2.0]])
    np.testing.assert_array_equal(sparse.rgb, [[200, 100, 50]])
    assert sparse.error.tolist() == [0.7] and sparse.track.tolist() == [1]
    assert sparse.source == f"sparse/0/points3D.{'bin' if binary else 'txt'}"


def test_validate_says_depth_is_absent_and_what_is_off(
    rgbd_scene: RgbdScene, tmp_path: Path
) -> None:
    root = remove_depth(write_colmap(rgbd_scene, tmp_path))
    report = validate_inputs(RunInputs(capture=root))
    assert report.ok
    out = format_report(report.summary, [])
    assert "layout: colmap" in out and "depth: absent (RGB-only capture)" in out
    assert "sparse_points: 1" in out and "depth loss (reconstruct.depth_weight)" in out
    assert "scale is arbitrary" in report.summary["capture"]["scale"]
    assert report.summary["capture"]["depth_valid_fraction"] == 0.0


def test_rgb_only_without_points_is_refused(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = remove_depth(write_colmap(rgbd_scene, tmp_path))
    (root / "sparse" / "0" / "points3D.bin").unlink()
    with pytest.raises(InputError) as info:
        read_capture(root)
    assert str(info.value).startswith(
        "sparse/0/points3D.bin: missing: an RGB-only COLMAP capture (no depth/ folder) is "
        "initialised from the sparse points"
    )
    report = validate_inputs(RunInputs(capture=root))
    assert [p.path for p in report.problems] == ["sparse/0/points3D.bin"]


@pytest.mark.parametrize(
    ("line", "reason"),
    [
        ("12 0.5 0.25", "expected POINT3D_ID X Y Z R G B ERROR then IMAGE_ID POINT2D_IDX pairs"),
        ("12 0.5 0.25 2.0 200 100 50 0.7 8", "then IMAGE_ID POINT2D_IDX pairs, got 9 values"),
        ("12 0.5 0.25 nan 200 100 50 0.7 8 1", "X Y Z must be finite"),
        ("12 0.5 0.25 2 300 100 50 0.7 8 1", "R G B must be in 0..255, got 300 100 50"),
        ("12 0.5 0.25 2 200 100 50 x 8 1", "X Y Z R G B ERROR must be numbers"),
    ],
)
def test_malformed_points3d_text_names_the_line(
    rgbd_scene: RgbdScene, tmp_path: Path, line: str, reason: str
) -> None:
    root = remove_depth(write_colmap(rgbd_scene, tmp_path, binary=False))
    (root / "sparse" / "0" / "points3D.txt").write_text(f"# points\n{line}\n")
    with pytest.raises(InputError) as info:
        read_capture(root)
    message = str(info.value)
    assert message.startswith("sparse/0/points3D.txt:line 2: ") and reason in message


def test_truncated_points3d_binary_names_the_point(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = remove_depth(write_colmap(rgbd_scene, tmp_path))
    path = root / "sparse" / "0" / "points3D.bin"
    path.write_bytes(path.read_bytes()[:-4])  # the track's last int32 cut off
    with pytest.raises(
        InputError,
        match=r"^sparse/0/points3D\.bin: truncated at byte 59: "
        r"point 1 \(id 12\): 1 track elements needs 8 bytes, 4 left",
    ):
        read_capture(root)


def test_capture_with_depth_refuses_to_be_rgb_only(rgbd_scene: RgbdScene) -> None:
    """``depth_source="none"`` promises all-0 depth: frames with depth contradict it."""
    frames = scene_capture(rgbd_scene).frames
    with pytest.raises(InputError, match="an RGB-only capture's depth must be all 0"):
        Capture(frames, "colmap", depth_source="none")


def test_zip_with_options(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    check_zip_with_options(rgbd_scene, write_colmap(rgbd_scene, tmp_path / "cap"), "colmap")


def test_validate_names_the_layout(tmp_path: Path) -> None:
    check_validate_names_layout(tmp_path, write_colmap, "colmap", CaptureOptions())


def test_synth_scene_as_colmap(tmp_path: Path) -> None:
    """A ``dcseg synth`` capture written as a binary COLMAP model reads back the same."""
    scene = capture_scene(synth_capture(tmp_path / "s"))
    check_round_trip(scene, write_colmap(scene, tmp_path / "colmap"))


def test_rgb_only_capture_is_not_written_as_a_manifest(
    rgbd_scene: RgbdScene, tmp_path: Path
) -> None:
    capture = read_capture(remove_depth(write_colmap(rgbd_scene, tmp_path / "c")))
    with pytest.raises(ValueError, match="RGB-only capture cannot be written"):
        write_capture(capture, tmp_path / "manifest")
    assert not (tmp_path / "manifest").exists()
