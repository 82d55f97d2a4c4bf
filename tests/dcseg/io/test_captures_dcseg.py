"""The dcseg manifest: writer/reader round trip and schema validation."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from dcseg.config import CaptureOptions
from dcseg.errors import InputError
from dcseg.io.captures import detect_layout, read_capture
from dcseg.io.captures.manifest import write_capture
from dcseg.io.images import write_image
from dcseg.types import Capture, Frame, Intrinsics
from tests.dcseg.io.layouts import RgbdScene, scene_capture


def _write(scene: RgbdScene, tmp_path: Path) -> Path:
    return write_capture(scene_capture(scene), tmp_path / "cap")


def _edit(manifest: Path, change) -> None:
    doc = json.loads(manifest.read_text())
    change(doc)
    manifest.write_text(json.dumps(doc))


def test_round_trip(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    manifest = _write(rgbd_scene, tmp_path)
    assert manifest.name == "capture.json"
    assert detect_layout(manifest.parent) == "dcseg"
    capture = read_capture(manifest.parent)
    assert capture.layout == "dcseg"
    assert capture.names == ("000000", "000001", "000002", "000003")
    for i, frame in enumerate(capture.frames):
        np.testing.assert_array_equal(frame.rgb, rgbd_scene.rgb[i])
        np.testing.assert_allclose(frame.depth, rgbd_scene.depth[i], atol=1e-3)
        np.testing.assert_array_equal(frame.c2w, rgbd_scene.c2w[i])
        assert frame.intrinsics == rgbd_scene.k
        assert frame.files["rgb"] == f"rgb/{frame.name}.png"
        assert frame.files["pose"] == f"capture.json:frames[{i}].c2w"


def test_format_doc(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    doc = json.loads(_write(rgbd_scene, tmp_path).read_text())
    assert doc["format"] == "dcseg.capture" and doc["version"] == 1
    assert doc["depth_scale"] == 1000.0
    assert set(doc["intrinsics"]) == {"fx", "fy", "cx", "cy", "width", "height"}
    assert doc["frames"][0]["depth"] == "depth/000000.png"


def test_far_depth_odd_names_and_per_frame_intrinsics(rgbd_scene: RgbdScene, tmp_path: Path):
    far = rgbd_scene.depth[1] * 30.0
    small = Intrinsics(10.0, 11.0, 3.5, 2.5, 8, 6)
    frames = (
        Frame(
            "seq-01/frame-000000",
            rgbd_scene.rgb[0],
            rgbd_scene.depth[0],
            rgbd_scene.k,
            rgbd_scene.c2w[0],
        ),
        Frame("../weird name", rgbd_scene.rgb[1], far, rgbd_scene.k, rgbd_scene.c2w[1]),
        Frame(
            "small",
            rgbd_scene.rgb[2][::2, ::2].copy(),
            rgbd_scene.depth[2][::2, ::2].copy(),
            small,
            rgbd_scene.c2w[2],
        ),
    )
    manifest = write_capture(Capture(frames, "7scenes"), tmp_path / "cap")
    doc = json.loads(manifest.read_text())
    assert doc["frames"][0]["rgb"] == "rgb/seq-01/frame-000000.png"
    assert doc["frames"][1]["depth"] == "depth/000001.npy"
    assert "intrinsics" in doc["frames"][2] and "intrinsics" not in doc["frames"][0]
    capture = read_capture(manifest.parent)
    assert capture.names == tuple(f.name for f in frames)
    np.testing.assert_array_equal(capture.frames[1].depth, far)
    assert capture.frames[2].intrinsics == small


def test_options_apply(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = _write(rgbd_scene, tmp_path).parent
    options = CaptureOptions(stride=2, max_frames=1, size=(8, 6), depth_trunc=2.0)
    capture = read_capture(root, options)
    assert capture.names == ("000000",)
    frame = capture.frames[0]
    assert frame.rgb.shape == (6, 8, 3) and frame.depth.shape == (6, 8)
    assert frame.intrinsics == rgbd_scene.k.scaled(8, 6)
    assert float(frame.depth.max()) <= 2.0


def test_missing_key_names_json_path(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    manifest = _write(rgbd_scene, tmp_path)
    _edit(manifest, lambda d: (d["frames"][3].pop("c2w"), d["frames"][1].pop("rgb")))
    with pytest.raises(InputError) as info:
        read_capture(manifest.parent)
    messages = [str(p) for p in info.value.problems]
    assert "capture.json: frames[3].c2w: missing" in messages
    assert "capture.json: frames[1].rgb: missing" in messages


@pytest.mark.parametrize(
    ("change", "match"),
    [
        (lambda d: d.update(format="other"), r"capture\.json: format: must be 'dcseg\.capture'"),
        (lambda d: d.update(version=2), r"capture\.json: version: must be 1"),
        (lambda d: d.pop("frames"), r"capture\.json: frames: missing"),
        (lambda d: d.update(frames={}), r"frames: must be an array"),
        (lambda d: d["intrinsics"].pop("fx"), r"intrinsics\.fx: missing"),
        (lambda d: d["intrinsics"].update(width=-3), r"intrinsics\.width: must be a positive"),
        (lambda d: d["frames"][0].update(c2w=[[1, 2]]), r"frames\[0\]\.c2w: must be a 4x4"),
        (lambda d: d["frames"][2].update(depth="/etc/passwd"), r"frames\[2\]\.depth: path"),
        (lambda d: d["frames"][2].update(rgb="../x.png"), r"must be relative to and inside"),
        (lambda d: d.update(depth_scale=0), r"depth_scale: must be > 0"),
    ],
)
def test_schema_errors(rgbd_scene: RgbdScene, tmp_path: Path, change, match: str) -> None:
    manifest = _write(rgbd_scene, tmp_path)
    _edit(manifest, change)
    with pytest.raises(InputError, match=match):
        read_capture(manifest.parent)


def test_invalid_json(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    manifest = _write(rgbd_scene, tmp_path)
    manifest.write_text('{"format": ')
    with pytest.raises(InputError, match=r"capture\.json: invalid JSON .*line 1"):
        read_capture(manifest.parent)


def test_missing_and_bad_files(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = _write(rgbd_scene, tmp_path).parent
    (root / "depth" / "000001.png").unlink()
    (root / "rgb" / "000002.png").write_bytes(b"not an image")
    stretched = np.diag([1.0, 2.0, 1.0, 1.0]).tolist()
    _edit(root / "capture.json", lambda d: d["frames"][3].update(c2w=stretched))
    with pytest.raises(InputError) as info:
        read_capture(root)
    messages = [str(p) for p in info.value.problems]
    assert messages[0] == "depth/000001.png: missing (colour rgb/000001.png has no depth)"
    assert "rgb/000002.png: cannot decode image (corrupt or not an image)" in messages
    assert any(m.startswith("capture.json:frames[3].c2w: pose is not a rigid") for m in messages)
    assert len(messages) == 3


def test_size_mismatch(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = _write(rgbd_scene, tmp_path).parent
    write_image(root / "depth" / "000000.png", np.zeros((6, 8), np.uint16))
    with pytest.raises(InputError, match=r"depth/000000\.png: depth size 8x6 does not match "):
        read_capture(root)


def test_empty_capture(tmp_path: Path) -> None:
    (tmp_path / "capture.json").write_text(
        json.dumps({"format": "dcseg.capture", "version": 1, "frames": []})
    )
    with pytest.raises(InputError, match="capture is empty"):
        read_capture(tmp_path)


def test_npy_depth_checks(rgbd_scene: RgbdScene, tmp_path: Path, monkeypatch) -> None:
    root = _write(rgbd_scene, tmp_path).parent
    np.save(root / "depth" / "x.npy", rgbd_scene.depth[0])
    _edit(root / "capture.json", lambda d: d["frames"][0].update(depth="depth/x.npy"))
    np.testing.assert_array_equal(read_capture(root).frames[0].depth, rgbd_scene.depth[0])
    monkeypatch.setattr("dcseg.io.images.MAX_PIXELS", 100)
    with pytest.raises(InputError, match=r"depth/x\.npy: depth array has 192 values, above"):
        read_capture(root, CaptureOptions(max_frames=1))
    (root / "depth" / "x.npy").write_bytes(b"junk")
    with pytest.raises(InputError, match=r"depth/x\.npy: cannot read \.npy depth"):
        read_capture(root, CaptureOptions(max_frames=1))


def test_colliding_file_stems(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    k, d = rgbd_scene.k, rgbd_scene.depth
    frames = (
        Frame("000001", rgbd_scene.rgb[0], d[0], k, rgbd_scene.c2w[0]),
        Frame("bad name", rgbd_scene.rgb[1], d[1], k, rgbd_scene.c2w[1]),
        Frame("a/./b", rgbd_scene.rgb[2], d[2], k, rgbd_scene.c2w[2]),
    )
    manifest = write_capture(Capture(frames, "dcseg"), tmp_path / "cap")
    stems = [f["rgb"] for f in json.loads(manifest.read_text())["frames"]]
    assert stems == ["rgb/000001.png", "rgb/_000001.png", "rgb/000002.png"]
    capture = read_capture(manifest.parent)
    assert capture.names == ("000001", "bad name", "a/./b")
    np.testing.assert_array_equal(capture.frames[1].rgb, rgbd_scene.rgb[1])


def test_target_size_above_the_frames_is_refused(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    """No upscaling beyond the capture: the reader names the frame file."""
    root = _write(rgbd_scene, tmp_path).parent
    frame = read_capture(root).frames[0]
    with pytest.raises(InputError, match="only ever downscaled") as caught:
        read_capture(root, CaptureOptions(size=(frame.width + 1, frame.height)))
    assert caught.value.problems[0].path.endswith(".png")
