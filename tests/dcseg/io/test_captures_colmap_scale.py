"""COLMAP models whose sparse points disagree with the depth maps in scale are refused.

Sparse points are made by back-projecting depth pixels, so each one's depth in its camera equals
the depth map there; scaling the model (poses and points) by ``s`` makes the ratio ``1 / s``."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

from dcseg.config import CaptureOptions
from dcseg.errors import InputError
from dcseg.io.captures import read_capture
from dcseg.io.captures.colmap_scale import MIN_POINTS
from tests.dcseg.io.layouts import RgbdScene, capture_scene, make_scene, synth_capture
from tests.dcseg.io.test_captures_colmap import remove_depth, world_to_camera, write_colmap

Observation = tuple[float, float, int]


def sparse_points(
    scene: RgbdScene, scale: float, step: int = 2
) -> tuple[dict[int, list[Observation]], dict[int, np.ndarray]]:
    """Per frame index: its observations (COLMAP x, y, point id); per point id: world xyz."""
    k = scene.k
    observed: dict[int, list[Observation]] = {}
    points: dict[int, np.ndarray] = {}
    for i in range(scene.n):
        observed[i] = []
        for v in range(0, k.height, step):
            for u in range(0, k.width, step):
                d = float(scene.depth[i][v, u])
                if d <= 0:
                    continue
                cam = np.array([(u - k.cx) / k.fx * d, (v - k.cy) / k.fy * d, d, 1.0])
                pid = len(points) + 1
                points[pid] = (scene.c2w[i] @ cam)[:3] * scale
                observed[i].append((u + 0.5, v + 0.5, pid))
    return observed, points


def write_model(scene: RgbdScene, root: Path, scale: float, binary: bool) -> Path:
    """``write_colmap``'s images and depth, with a model scaled by ``scale``."""
    write_colmap(scene, root, binary=binary)  # images/, depth/, cameras
    folder = root / "sparse" / "0"
    observed, points = sparse_points(scene, scale)
    rows = []
    for i in range(scene.n):
        c2w = scene.c2w[i].copy()
        c2w[:3, 3] *= scale
        rows.append((i + 1, *world_to_camera(c2w), f"frame_{i}.png", observed[i]))
    if binary:
        out = struct.pack("<Q", len(rows))
        for iid, q, t, name, obs in rows:
            out += struct.pack("<i7di", iid, *q, *t, 1) + name.encode() + b"\x00"
            out += struct.pack("<Q", len(obs)) + b"".join(struct.pack("<ddq", *o) for o in obs)
        (folder / "images.bin").write_bytes(out)
        out = struct.pack("<Q", len(points))
        for pid, xyz in points.items():
            out += struct.pack("<QdddBBBd", pid, *xyz, 128, 128, 128, 0.5)
            out += struct.pack("<Q", 1) + struct.pack("<ii", 1, 0)
        (folder / "points3D.bin").write_bytes(out)
    else:
        lines = ["# images"]
        for iid, q, t, name, obs in rows:
            lines.append(" ".join(str(v) for v in (iid, *q, *t, 1, name)))
            lines.append(" ".join(f"{x} {y} {pid}" for x, y, pid in obs))
        (folder / "images.txt").write_text("\n".join(lines) + "\n")
        text = [
            f"{pid} {float(xyz[0])!r} {float(xyz[1])!r} {float(xyz[2])!r} 1 2 3 0.5 1 0"
            for pid, xyz in points.items()
        ]
        (folder / "points3D.txt").write_text("# points\n" + "\n".join(text) + "\n")
    return root


@pytest.mark.parametrize("binary", [True, False])
def test_consistent_model_is_read(tmp_path: Path, binary: bool) -> None:
    scene = make_scene(n=4)
    capture = read_capture(write_model(scene, tmp_path, 1.0, binary))
    assert len(capture) == 4
    np.testing.assert_allclose(capture.frames[2].c2w, scene.c2w[2], atol=1e-9)


@pytest.mark.parametrize("binary", [True, False])
def test_model_at_another_scale_is_refused(tmp_path: Path, binary: bool) -> None:
    scene = make_scene(n=4)
    root = write_model(scene, tmp_path, 2.5, binary)
    with pytest.raises(InputError) as info:
        read_capture(root)
    suffix = "bin" if binary else "txt"
    message = str(info.value)
    assert message.startswith(
        f"sparse/0/points3D.{suffix}: the model and the depth maps disagree in scale: depth map "
        "/ model depth at "
    )
    assert "has median 0.4 (expected 1): scale the model to metres" in message


def test_too_few_points_skip_the_check(tmp_path: Path) -> None:
    scene = make_scene(n=1, width=8, height=6)  # 12 grid points, 1 frame
    observed, _ = sparse_points(scene, 1.0)
    assert len(observed[0]) < MIN_POINTS
    assert len(read_capture(write_model(scene, tmp_path, 3.0, True))) == 1


def test_truncated_points_file(tmp_path: Path) -> None:
    root = write_model(make_scene(n=2), tmp_path, 1.0, True)
    points = root / "sparse" / "0" / "points3D.bin"
    raw = points.read_bytes()
    points.write_bytes(raw[: len(raw) // 2 + 5])
    with pytest.raises(InputError, match=r"^sparse/0/points3D\.bin: truncated"):
        read_capture(root)


def test_synth_scene_with_sparse_points(tmp_path: Path) -> None:
    """A ``dcseg synth`` capture as a COLMAP model with sparse points: read at its own scale,
    refused at another."""
    original = synth_capture(tmp_path / "s")
    scene = capture_scene(original)
    capture = read_capture(write_model(scene, tmp_path / "metric", 1.0, True))
    for frame, before in zip(capture.frames, original.frames, strict=True):
        np.testing.assert_allclose(frame.c2w, before.c2w, atol=1e-9)
        np.testing.assert_allclose(frame.depth, before.depth, atol=1e-6)
    with pytest.raises(InputError, match=r"disagree in scale: .* has median 0\.5 "):
        read_capture(write_model(scene, tmp_path / "sfm", 2.0, False))


@pytest.mark.parametrize("binary", [True, False])
def test_pose_scale_makes_a_scaled_model_metric(tmp_path: Path, binary: bool) -> None:
    """A model 2.5x too large, read with ``pose_scale`` 0.4: the check passes and the poses
    come back in metres; a wrong ``pose_scale`` is refused naming it."""
    scene = make_scene(n=4)
    root = write_model(scene, tmp_path, 2.5, binary)
    capture = read_capture(root, CaptureOptions(pose_scale=0.4))
    for frame, c2w in zip(capture.frames, scene.c2w, strict=True):
        np.testing.assert_allclose(frame.c2w, c2w, atol=1e-9)
    with pytest.raises(InputError) as info:
        read_capture(root, CaptureOptions(pose_scale=2.0))
    assert "depth map / (model depth x pose_scale 2) at " in str(info.value)
    assert "has median 0.2 (expected 1)" in str(info.value)


def test_pose_scale_scales_rgb_only_poses_and_sparse_points(tmp_path: Path) -> None:
    root = remove_depth(write_model(make_scene(n=3), tmp_path, 1.0, True))
    plain = read_capture(root)
    scaled = read_capture(root, CaptureOptions(pose_scale=0.25))
    assert plain.sparse is not None and scaled.sparse is not None
    np.testing.assert_allclose(scaled.sparse.xyz, plain.sparse.xyz * 0.25)
    for a, b in zip(scaled.frames, plain.frames, strict=True):
        np.testing.assert_allclose(a.c2w[:3, 3], b.c2w[:3, 3] * 0.25)
        np.testing.assert_array_equal(a.c2w[:3, :3], b.c2w[:3, :3])


@pytest.mark.parametrize("value", [0.0, -1.0, 2e6])
def test_pose_scale_out_of_range_is_refused(value: float) -> None:
    with pytest.raises(ValueError, match="pose_scale"):
        CaptureOptions(pose_scale=value)


@pytest.mark.parametrize(
    ("bad", "message"), [("1.2x", "expected X Y Z numbers"), ("nan", "X Y Z must be finite")]
)
def test_malformed_sparse_point_is_named(tmp_path: Path, bad: str, message: str) -> None:
    root = write_model(make_scene(), tmp_path, 1.0, binary=False)
    path = root / "sparse" / "0" / "points3D.txt"
    lines = path.read_text().splitlines()
    fields = lines[1].split()
    lines[1] = " ".join([fields[0], bad, *fields[2:]])
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError) as info:
        read_capture(root)
    assert str(info.value).startswith(f"sparse/0/points3D.txt:line 2: {message}, got '{bad} ")
