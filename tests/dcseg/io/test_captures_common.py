"""What all layouts share: detection, archive inputs, options, image helpers."""

from __future__ import annotations

import tarfile
import zipfile
from pathlib import Path

import numpy as np
import pytest

from dcseg.config import CaptureOptions
from dcseg.errors import InputError
from dcseg.io import images
from dcseg.io.captures import detect_layout, read_capture
from dcseg.io.captures.manifest import write_capture
from tests.dcseg.io.layouts import (
    RgbdScene,
    scene_capture,
    write_7scenes,
    write_nerfstudio,
    write_replica,
    write_scannet,
)


def _zip_folder(folder: Path, archive: Path, prefix: str = "") -> Path:
    with zipfile.ZipFile(archive, "w") as zf:
        for path in sorted(folder.rglob("*")):
            zf.write(path, prefix + path.relative_to(folder).as_posix())
    return archive


@pytest.mark.parametrize(
    ("writer", "layout"),
    [
        (lambda s, p: write_capture(scene_capture(s), p).parent, "dcseg"),
        (write_scannet, "scannet"),
        (write_replica, "replica"),
        (write_nerfstudio, "nerfstudio"),
        (lambda s, p: write_7scenes(s, p, "seq-01"), "7scenes"),
    ],
)
def test_detection_and_options_for_every_layout(rgbd_scene: RgbdScene, tmp_path, writer, layout):
    root = writer(rgbd_scene, tmp_path / "cap")
    assert detect_layout(root) == layout
    options = CaptureOptions(
        stride=2, max_frames=1, size=(8, 6), depth_trunc=2.0, intrinsics=(20.0, 22.0, 7.5, 5.5)
    )
    capture = read_capture(root, options)
    assert capture.layout == layout and len(capture) == 1
    frame = capture.frames[0]
    assert frame.rgb.shape == (6, 8, 3) and frame.depth.shape == (6, 8)
    assert frame.intrinsics == rgbd_scene.k.scaled(8, 6)
    expected = images.resize_nearest(rgbd_scene.depth[0], (8, 6))
    expected = np.where(expected > 2.0, 0.0, expected)
    np.testing.assert_allclose(frame.depth, expected, atol=2e-4)


def test_stride_and_max_frames(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = write_scannet(rgbd_scene, tmp_path)
    assert read_capture(root, CaptureOptions(stride=3)).names == ("0", "3")
    assert read_capture(root, CaptureOptions(max_frames=2)).names == ("0", "1")
    assert read_capture(str(root), CaptureOptions(stride=2, max_frames=5)).names == ("0", "2")


def test_image_problems_only_for_selected_frames(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = write_scannet(rgbd_scene, tmp_path)
    (root / "color" / "1.png").write_bytes(b"junk")
    assert read_capture(root, CaptureOptions(stride=2)).names == ("0", "2")
    (root / "depth" / "3.png").unlink()
    with pytest.raises(InputError, match=r"depth/3\.png: missing"):
        read_capture(root, CaptureOptions(stride=2))


def test_zip_input(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = write_scannet(rgbd_scene, tmp_path / "scan")
    archive = _zip_folder(root, tmp_path / "scan.zip", prefix="scene0000_00/")
    capture = read_capture(archive)
    assert capture.layout == "scannet" and len(capture) == 4
    assert capture.root == str(archive)
    np.testing.assert_array_equal(capture.frames[2].rgb, rgbd_scene.rgb[2])


@pytest.mark.parametrize("suffix", [".tar", ".tar.gz", ".tgz"])
def test_tar_input(rgbd_scene: RgbdScene, tmp_path: Path, suffix: str) -> None:
    root = write_nerfstudio(rgbd_scene, tmp_path / "scene")
    archive = tmp_path / f"scene{suffix}"
    with tarfile.open(archive, "w:gz" if suffix != ".tar" else "w") as tf:
        for path in sorted(root.iterdir()):
            tf.add(path, path.name)  # files at the archive root
    capture = read_capture(archive)
    assert capture.layout == "nerfstudio" and len(capture) == 4


def test_archive_errors_name_the_archive(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    bad = tmp_path / "broken.zip"
    bad.write_bytes(b"PK\x03\x04 not really a zip")
    with pytest.raises(InputError, match=r"broken\.zip: not a supported archive"):
        read_capture(bad)
    empty = _zip_folder(tmp_path / "nothing", tmp_path / "empty.zip")
    with pytest.raises(InputError, match=r"no capture layout recognised in .*empty\.zip"):
        read_capture(empty)


def test_unknown_layout_and_bad_paths(tmp_path: Path) -> None:
    (tmp_path / "notes.txt").write_text("hi")
    expected = (
        r"no capture layout recognised in .*: expected one of capture\.json, "
        r"color/\+depth/\+pose/, results/\+traj\.txt, transforms\.json, metadata\+rgbd/, "
        r"metadata\.json\+rgb/\+depth/, "
        r"keyframes/images\+cameras/, frame-\*\.color\.\*, rgb\.txt\+depth\.txt, "
        r"sparse/0/cameras\+images\.bin\|txt, image\|rgb\|color/\+depth/\+\*\.log, "
        r"lowres_wide/\+lowres_wide\.traj, rgb/\+pose_intrinsic_imu\.json"
    )
    with pytest.raises(InputError, match=expected):
        read_capture(tmp_path)
    with pytest.raises(InputError, match="does not exist"):
        read_capture(tmp_path / "nope")
    with pytest.raises(InputError, match=r"not a folder, a \.zip.*or a \.r3d file"):
        read_capture(tmp_path / "notes.txt")


def test_empty_layout_folder(tmp_path: Path) -> None:
    for sub in ("color", "depth", "pose", "intrinsic"):
        (tmp_path / sub).mkdir()
    np.savetxt(tmp_path / "intrinsic" / "intrinsic_color.txt", np.eye(4))
    with pytest.raises(InputError, match="capture is empty: no frames found"):
        read_capture(tmp_path)


def test_read_image_errors(tmp_path: Path) -> None:
    with pytest.raises(InputError, match=r"^a/missing\.png: missing$"):
        images.read_image(tmp_path / "a" / "missing.png", root=tmp_path)
    (tmp_path / "empty.png").write_bytes(b"")
    with pytest.raises(InputError, match="file is empty"):
        images.read_image(tmp_path / "empty.png")
    good = images.write_png(tmp_path / "x.png", np.zeros((12, 16, 3), np.uint8))
    data = good.read_bytes()
    (tmp_path / "cut.png").write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match=r"^cut\.png: cannot decode image"):
        images.read_image(tmp_path / "cut.png", root=tmp_path)


def test_read_image_pixel_limit(tmp_path: Path, monkeypatch) -> None:
    path = images.write_png(tmp_path / "big.png", np.zeros((12, 16), np.uint8))
    assert images.image_size(path) == (16, 12)
    monkeypatch.setattr(images, "MAX_PIXELS", 100)
    with pytest.raises(InputError, match=r"image is 16x12 pixels, above the limit of 100 pixels"):
        images.read_image(path)
    jpg = images.write_image(tmp_path / "big.jpg", np.zeros((12, 16, 3), np.uint8))
    assert images.image_size(jpg) == (16, 12)
    with pytest.raises(InputError, match="above the limit"):
        images.read_image(jpg)


def test_image_round_trip_and_resize(tmp_path: Path) -> None:
    rgba = np.random.default_rng(0).integers(0, 256, (12, 16, 4), dtype=np.uint8)
    np.testing.assert_array_equal(images.read_image(images.write_png(tmp_path / "a", rgba)), rgba)
    depth = np.arange(16 * 12, dtype=np.uint16).reshape(12, 16)
    back = images.read_image(images.write_png(tmp_path / "d.png", depth))
    assert back.dtype == np.uint16
    np.testing.assert_array_equal(back, depth)
    labels = np.arange(4, dtype=np.int64).reshape(2, 2)
    np.testing.assert_array_equal(
        images.resize_nearest(labels, (4, 4)), np.repeat(np.repeat(labels, 2, 0), 2, 1)
    )
    np.testing.assert_array_equal(images.resize_nearest(depth, (8, 6)), depth[1::2, 1::2])
    flat = np.full((12, 16, 3), 77, np.uint8)
    np.testing.assert_array_equal(images.resize_area(flat, (8, 6)), flat[:6, :8])
