"""Raw ScanNet ``.sens`` files, written with struct per the byte layout of ScanNet's reference
reader (SensReader/python/SensorData.py, version 4)."""

from __future__ import annotations

import logging
import struct
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest

from dcseg.errors import InputError
from dcseg.inputs import RunInputs
from dcseg.io.captures import read_capture
from dcseg.io.validate import validate_inputs
from dcseg.types import Intrinsics
from tests.dcseg.io.layouts import RgbdScene, k4, make_scene, mm

PNG, JPEG = 1, 2
RAW_USHORT, ZLIB_USHORT = 0, 1


def header(scene: RgbdScene, colour: int = PNG, depth: int = ZLIB_USHORT, **over: float) -> bytes:
    k, h, w = scene.k, scene.k.height, scene.k.width
    name = b"StructureSensor"
    out = struct.pack("<IQ", int(over.get("version", 4)), len(name)) + name
    for matrix in (k4(k), np.eye(4), k4(k), np.eye(4)):  # depth registered at the same size
        out += struct.pack("<16f", *matrix.ravel())
    out += struct.pack("<iiIIII", colour, depth, w, h, w, h)
    out += struct.pack("<fQ", over.get("shift", 1000.0), scene.n)
    return out


def frame(c2w: np.ndarray, rgb: np.ndarray, depth: np.ndarray, colour: int, codec: int) -> bytes:
    ok, encoded = cv2.imencode(".png" if colour == PNG else ".jpg", rgb[:, :, ::-1])
    assert ok
    raw = mm(depth).astype("<u2").tobytes()
    packed = zlib.compress(raw) if codec == ZLIB_USHORT else raw
    out = struct.pack("<16f", *c2w.ravel()) + struct.pack("<QQ", 1000, 1001)
    out += struct.pack("<QQ", len(encoded.tobytes()), len(packed))
    return out + encoded.tobytes() + packed


def write_sens(
    scene: RgbdScene, path: Path, colour: int = PNG, depth: int = ZLIB_USHORT, **over: float
) -> Path:
    body = header(scene, colour, depth, **over)
    for i in range(scene.n):
        body += frame(scene.c2w[i], scene.rgb[i], scene.depth[i], colour, depth)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(body)
    return path


def float32_scene(scene: RgbdScene) -> RgbdScene:
    """The scene with its poses as .sens stores them (float32)."""
    c2w = [p.astype(np.float32).astype(np.float64) for p in scene.c2w]
    return RgbdScene(scene.rgb, scene.depth, c2w, scene.k)


@pytest.mark.parametrize("codec", [ZLIB_USHORT, RAW_USHORT])
def test_round_trip(rgbd_scene: RgbdScene, tmp_path: Path, codec: int) -> None:
    path = write_sens(rgbd_scene, tmp_path / "scene0000_00.sens", depth=codec)
    capture = read_capture(path)
    assert capture.layout == "scannet-sens" and capture.root == str(path)
    assert capture.names == ("0", "1", "2", "3")
    expected = float32_scene(rgbd_scene)
    for i, f in enumerate(capture.frames):
        np.testing.assert_array_equal(f.rgb, rgbd_scene.rgb[i])
        np.testing.assert_allclose(f.depth, rgbd_scene.depth[i], atol=1e-6)
        np.testing.assert_allclose(f.c2w, expected.c2w[i], atol=1e-6)
        assert f.intrinsics == rgbd_scene.k
    report = validate_inputs(RunInputs(capture=path))
    assert report.ok and report.summary["capture"]["layout"] == "scannet-sens"


def test_jpeg_colour_and_lost_tracking(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    scene = make_scene(n=3, width=32, height=24)
    scene.c2w[1][:] = -np.inf  # ScanNet's mark for a lost pose
    path = write_sens(scene, tmp_path / "s.sens", colour=JPEG)
    with caplog.at_level(logging.WARNING):
        capture = read_capture(path)
    assert capture.names == ("0", "2")
    assert "skipping 1 ScanNet frame(s) whose pose contains inf" in caplog.text
    assert np.abs(capture.frames[0].rgb.astype(int) - scene.rgb[0]).mean() < 60  # lossy JPEG
    assert capture.frames[0].files["rgb"] == "color/0.jpg"


def test_malformed_files(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    path = write_sens(rgbd_scene, tmp_path / "a.sens")
    raw = path.read_bytes()
    path.write_bytes(raw[:-10])
    with pytest.raises(InputError) as info:
        read_capture(path)
    assert str(info.value).startswith(f"{path}: truncated at byte ")
    assert "frame 3: depth needs" in str(info.value)
    write_sens(rgbd_scene, path, version=3)
    with pytest.raises(InputError) as info:
        read_capture(path)
    assert str(info.value) == f"{path}: version 3: only version 4 is read"
    write_sens(rgbd_scene, path, shift=5000.0)
    with pytest.raises(InputError) as info:
        read_capture(path)
    assert str(info.value).startswith(
        f"{path}: depth shift 5000 is not supported (dcseg reads 1000"
    )
    write_sens(rgbd_scene, path, depth=2)
    with pytest.raises(InputError, match=r"depth compression occi_ushort is not supported"):
        read_capture(path)
    write_sens(rgbd_scene, path, colour=0)
    with pytest.raises(InputError, match=r"colour compression raw is not supported"):
        read_capture(path)


def test_depth_of_the_wrong_size(tmp_path: Path) -> None:
    scene = make_scene(n=1)
    body = header(scene)
    small = RgbdScene(scene.rgb, [scene.depth[0][:6]], scene.c2w, scene.k)
    body += frame(small.c2w[0], small.rgb[0], small.depth[0], PNG, ZLIB_USHORT)
    path = tmp_path / "b.sens"
    path.write_bytes(body)
    with pytest.raises(InputError) as info:
        read_capture(path)
    assert str(info.value) == (
        f"{path}: frame 0: depth holds 192 bytes, expected 384 (16x12 uint16)"
    )
    raw_depth = frame(scene.c2w[0], scene.rgb[0], scene.depth[0], PNG, RAW_USHORT)
    path.write_bytes(header(scene) + raw_depth)  # the header says zlib
    with pytest.raises(InputError, match=r"frame 0: depth is not zlib data"):
        read_capture(path)


def test_synth_scene_as_sens(tmp_path: Path) -> None:
    """A ``dcseg synth`` capture written as a .sens reads back the same."""
    pytest.importorskip("pybullet")
    from dcseg.synth import SynthConfig, generate_scene, write_scene

    # what `dcseg synth s --frames 6 --size 64x48` writes
    write_scene(generate_scene(SynthConfig(seed=0, frames=6, width=64, height=48)), tmp_path / "s")
    original = read_capture(tmp_path / "s")
    k = original.frames[0].intrinsics
    scene = RgbdScene(
        [f.rgb for f in original.frames],
        [f.depth for f in original.frames],
        [f.c2w for f in original.frames],
        Intrinsics(k.fx, k.fy, k.cx, k.cy, k.width, k.height),
    )
    capture = read_capture(write_sens(scene, tmp_path / "synth.sens"))
    assert len(capture) == 6
    for f, before in zip(capture.frames, original.frames, strict=True):
        np.testing.assert_array_equal(f.rgb, before.rgb)
        np.testing.assert_allclose(f.depth, before.depth, atol=1e-6)
        np.testing.assert_allclose(f.c2w, before.c2w, atol=1e-6)
        np.testing.assert_allclose(
            [f.intrinsics.fx, f.intrinsics.cx], [before.intrinsics.fx, before.intrinsics.cx], 1e-6
        )
