"""Tiny RGB-D scenes written in each capture layout (fixtures are generated, never committed).

Format fixtures, not shared scenes: depth in whole millimetres and a few invalid pixels, so
that every layout's writer and reader round-trip it exactly."""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pytest
from numpy.typing import NDArray

from dcseg.cli.validate import format_report
from dcseg.config import CaptureOptions
from dcseg.inputs import RunInputs
from dcseg.io.captures import read_capture
from dcseg.io.images import write_image
from dcseg.io.validate import validate_inputs
from dcseg.types import Capture, Frame, Intrinsics

GL = np.diag([1.0, -1.0, -1.0, 1.0])


@dataclass(frozen=True)
class RgbdScene:
    """Ground truth for a written capture: what every reader must give back."""

    rgb: list[NDArray[np.uint8]]
    depth: list[NDArray[np.float32]]  # metres, multiples of 1 mm, 0 = invalid
    c2w: list[NDArray[np.float64]]
    k: Intrinsics

    @property
    def n(self) -> int:
        return len(self.rgb)


def make_scene(n: int = 4, width: int = 16, height: int = 12, seed: int = 0) -> RgbdScene:
    rng = np.random.default_rng(seed)
    rgb = [rng.integers(0, 256, (height, width, 3), dtype=np.uint8) for _ in range(n)]
    depth = []
    for _ in range(n):
        d = np.round(rng.uniform(0.5, 4.0, (height, width)), 3).astype(np.float32)
        d[0, :3] = 0.0
        depth.append(d)
    c2w = []
    for _ in range(n):
        pose = np.eye(4)
        pose[:3, :3] = cv2.Rodrigues(rng.normal(size=3))[0]
        pose[:3, 3] = rng.normal(size=3)
        c2w.append(pose)
    k = Intrinsics(20.0, 22.0, 7.5, 5.5, width, height)
    return RgbdScene(rgb, depth, c2w, k)


def scene_capture(scene: RgbdScene) -> Capture:
    frames = tuple(
        Frame(f"{i:06d}", scene.rgb[i], scene.depth[i], scene.k, scene.c2w[i])
        for i in range(scene.n)
    )
    return Capture(frames, "dcseg")


def assert_same_frames(
    got: Sequence[Frame], expected: Sequence[Frame], pose_atol: float, depth_atol: float = 1e-6
) -> None:
    """What every layout's round trip checks: as many frames, colour exact, depth and pose
    within the layout's precision, the same intrinsics."""
    assert len(got) == len(expected)
    for frame, before in zip(got, expected, strict=True):
        np.testing.assert_array_equal(frame.rgb, before.rgb)
        np.testing.assert_allclose(frame.depth, before.depth, atol=depth_atol)
        np.testing.assert_allclose(frame.c2w, before.c2w, atol=pose_atol)
        assert frame.intrinsics == before.intrinsics


def synth_capture(root: Path) -> Capture:
    """What ``dcseg synth s --frames 6 --size 64x48`` writes at ``root``, read back: rendered
    geometry (not noise) for a layout's writer to carry. Skips without pybullet."""
    pytest.importorskip("pybullet")
    from dcseg.synth import SynthConfig, generate_scene, write_scene

    write_scene(generate_scene(SynthConfig(seed=0, frames=6, width=64, height=48)), root)
    return read_capture(root)


def capture_scene(capture: Capture) -> RgbdScene:
    """A read capture as the ground truth the layout writers take (the first frame's intrinsics)."""
    return RgbdScene(
        [f.rgb for f in capture.frames],
        [f.depth for f in capture.frames],
        [f.c2w for f in capture.frames],
        capture.frames[0].intrinsics,
    )


def check_validate_names_layout(
    tmp_path: Path,
    write: Callable[[RgbdScene, Path], Path],
    layout: str,
    options: CaptureOptions | None = None,
) -> None:
    """``dcseg validate`` on a two-frame scene written by ``write`` passes and names ``layout``."""
    report = validate_inputs(RunInputs(capture=write(make_scene(n=2), tmp_path)), options)
    assert report.ok
    out = format_report(report.summary, [])
    assert f"layout: {layout}" in out and "frames: 2" in out


def check_synth_round_trip(
    tmp_path: Path, write: Callable[[RgbdScene, Path], Path], pose_atol: float
) -> None:
    """A ``dcseg synth`` capture written by ``write`` (into ``tmp_path``) reads back the same."""
    original = synth_capture(tmp_path / "s")
    capture = read_capture(write(capture_scene(original), tmp_path / "written"))
    assert len(capture) == 6
    assert_same_frames(capture.frames, original.frames, pose_atol)


def k4(k: Intrinsics) -> NDArray[np.float64]:
    out = np.eye(4)
    out[:3, :3] = k.matrix()
    return out


def mm(depth: NDArray[np.float32]) -> NDArray[np.uint16]:
    out: NDArray[np.uint16] = np.rint(depth * 1000.0).astype(np.uint16)
    return out


def write_scannet(
    scene: RgbdScene, root: Path, ext: str = ".png", depth_half: bool = False
) -> Path:
    for i in range(scene.n):
        write_image(root / "color" / f"{i}{ext}", scene.rgb[i])
        depth = mm(scene.depth[i])
        if depth_half:
            depth = depth[::2, ::2]
        write_image(root / "depth" / f"{i}.png", depth)
        (root / "pose").mkdir(parents=True, exist_ok=True)
        np.savetxt(root / "pose" / f"{i}.txt", scene.c2w[i])
    (root / "intrinsic").mkdir(parents=True, exist_ok=True)
    np.savetxt(root / "intrinsic" / "intrinsic_color.txt", k4(scene.k))
    if depth_half:
        np.savetxt(root / "intrinsic" / "intrinsic_depth.txt", k4(scene.k.scaled(8, 6)))
    return root


def write_replica(
    scene: RgbdScene, root: Path, cam_params: bool = True, extra_rows: int = 3
) -> Path:
    for i in range(scene.n):
        write_image(root / "results" / f"frame{i:06d}.png", scene.rgb[i])
        raw = np.rint(scene.depth[i] * 6553.5).astype(np.uint16)
        write_image(root / "results" / f"depth{i:06d}.png", raw)
    rows = [*scene.c2w, *([np.eye(4)] * extra_rows)]
    lines = [" ".join(repr(float(v)) for v in pose.ravel()) for pose in rows]
    (root / "traj.txt").write_text("\n".join(lines) + "\n")
    if cam_params:
        k = scene.k
        camera = {"w": k.width, "h": k.height, "fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy}
        (root / "cam_params.json").write_text(json.dumps({"camera": {**camera, "scale": 6553.5}}))
    return root


def nerfstudio_doc(scene: RgbdScene) -> dict[str, object]:
    k = scene.k
    frames = [
        {
            "file_path": f"images/frame_{i:05d}.png",
            "depth_file_path": f"depth/frame_{i:05d}.png",
            "transform_matrix": (scene.c2w[i] @ GL).tolist(),
        }
        for i in range(scene.n)
    ]
    return {
        "fl_x": k.fx,
        "fl_y": k.fy,
        "cx": k.cx,
        "cy": k.cy,
        "w": k.width,
        "h": k.height,
        "frames": frames,
    }


def write_nerfstudio(scene: RgbdScene, root: Path, doc: dict[str, object] | None = None) -> Path:
    for i in range(scene.n):
        write_image(root / "images" / f"frame_{i:05d}.png", scene.rgb[i])
        write_image(root / "depth" / f"frame_{i:05d}.png", mm(scene.depth[i]))
    (root / "transforms.json").write_text(json.dumps(doc or nerfstudio_doc(scene)))
    return root


def write_7scenes(scene: RgbdScene, root: Path, sub: str | None = None) -> Path:
    folder = root / sub if sub else root
    for i in range(scene.n):
        write_image(folder / f"frame-{i:06d}.color.png", scene.rgb[i])
        write_image(folder / f"frame-{i:06d}.depth.png", mm(scene.depth[i]))
        np.savetxt(folder / f"frame-{i:06d}.pose.txt", scene.c2w[i])
    return root
