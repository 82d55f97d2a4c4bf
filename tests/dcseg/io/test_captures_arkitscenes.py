"""ARKitScenes layout: fixtures written per the dataset's files (DATA.md) as its own loader
(threedod/benchmark_scripts/utils/tenFpsDataLoader.py) reads them: ``.traj`` lines of
timestamp, axis-angle and translation of the world-to-camera transform."""

from __future__ import annotations

import logging
from pathlib import Path

import cv2
import numpy as np
import pytest

from dcseg.config import CaptureOptions
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

VIDEO = "41069021"
T0 = 3052.083


def stamp(i: int) -> str:
    return f"{T0 + 0.1 * i:.3f}"


def traj_line(t: float, c2w: np.ndarray) -> str:
    w2c = np.linalg.inv(c2w)
    rvec, _ = cv2.Rodrigues(w2c[:3, :3])
    return " ".join(f"{v:.17g}" for v in [t, *rvec.ravel(), *w2c[:3, 3]])


def write_arkitscenes(scene: RgbdScene, root: Path, pose_offset: float = 0.002) -> Path:
    """``<video>_frames/`` with poses ``pose_offset`` s after each frame (within 5 ms)."""
    folder = root / f"{VIDEO}_frames"
    lines = []
    k = scene.k
    for i in range(scene.n):
        name = f"{VIDEO}_{stamp(i)}"
        write_image(folder / "lowres_wide" / f"{name}.png", scene.rgb[i])
        write_image(folder / "lowres_depth" / f"{name}.png", mm(scene.depth[i]))
        write_image(
            folder / "confidence" / f"{name}.png", np.full(scene.depth[i].shape, 2, np.uint8)
        )
        pincam = folder / "lowres_wide_intrinsics" / f"{name}.pincam"
        pincam.parent.mkdir(parents=True, exist_ok=True)
        pincam.write_text(f"{k.width} {k.height} {k.fx} {k.fy} {k.cx} {k.cy}\n")
        lines.append(traj_line(float(stamp(i)) + pose_offset, scene.c2w[i]))
    (folder / "lowres_wide.traj").write_text("\n".join(lines) + "\n")
    return root


def test_round_trip(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = write_arkitscenes(rgbd_scene, tmp_path)
    assert detect_layout(root) == "arkitscenes"
    capture = read_capture(root, CaptureOptions(min_confidence=2))
    assert capture.layout == "arkitscenes"
    assert capture.names == tuple(f"{VIDEO}_{stamp(i)}" for i in range(4))
    assert_same_frames(capture.frames, scene_capture(rgbd_scene).frames, pose_atol=1e-9)
    assert capture.frames[2].files["pose"] == f"{VIDEO}_frames/lowres_wide.traj:line 3"
    assert capture.frames[2].files["confidence"] == (
        f"{VIDEO}_frames/confidence/{VIDEO}_{stamp(2)}.png"
    )


def test_frames_folder_itself_and_pincam_named_1ms_off(
    rgbd_scene: RgbdScene, tmp_path: Path
) -> None:
    folder = write_arkitscenes(rgbd_scene, tmp_path) / f"{VIDEO}_frames"
    pincam = folder / "lowres_wide_intrinsics" / f"{VIDEO}_{stamp(1)}.pincam"
    pincam.rename(pincam.with_name(f"{VIDEO}_{float(stamp(1)) + 0.001:.3f}.pincam"))
    capture = read_capture(folder)
    assert capture.frames[1].files["intrinsics"].endswith(f"{float(stamp(1)) + 0.001:.3f}.pincam")


def test_frames_without_pose_are_dropped(
    rgbd_scene: RgbdScene, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    root = write_arkitscenes(rgbd_scene, tmp_path)
    traj = root / f"{VIDEO}_frames" / "lowres_wide.traj"
    lines = traj.read_text().splitlines()
    traj.write_text("\n".join(lines[1:]) + "\n")
    with caplog.at_level(logging.WARNING):
        capture = read_capture(root)
    assert capture.names == tuple(f"{VIDEO}_{stamp(i)}" for i in range(1, 4))
    assert "1 of 4 frames have no pose within 5 ms" in caplog.text
    root = write_arkitscenes(rgbd_scene, tmp_path / "late", pose_offset=0.006)
    with pytest.raises(InputError) as info:
        read_capture(root)
    assert str(info.value) == (
        f"{VIDEO}_frames/lowres_wide.traj: no lowres_wide frame has a pose within 5 ms"
    )
    assert len(read_capture(root, CaptureOptions(sync_tolerance_ms=7))) == 4


def test_malformed_files(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = write_arkitscenes(rgbd_scene, tmp_path)
    folder = root / f"{VIDEO}_frames"
    traj = folder / "lowres_wide.traj"
    lines = traj.read_text().splitlines()
    traj.write_text("\n".join([lines[0], " ".join(lines[1].split()[:6]), *lines[2:]]) + "\n")
    with pytest.raises(InputError) as info:
        read_capture(root)
    assert str(info.value) == (
        f"{VIDEO}_frames/lowres_wide.traj:line 2: expected 7 values "
        "(timestamp rx ry rz tx ty tz), got 6"
    )
    traj.write_text("\n".join(lines) + "\n")
    (folder / "lowres_wide_intrinsics" / f"{VIDEO}_{stamp(1)}.pincam").write_text("256 192 1\n")
    (folder / "lowres_wide_intrinsics" / f"{VIDEO}_{stamp(2)}.pincam").unlink()
    (folder / "lowres_depth" / f"{VIDEO}_{stamp(3)}.png").unlink()
    with pytest.raises(InputError) as info:
        read_capture(root)
    intr = f"{VIDEO}_frames/lowres_wide_intrinsics/{VIDEO}"
    assert [str(p) for p in info.value.problems] == [
        f"{intr}_{stamp(1)}.pincam: expected 6 numbers 'width height fx fy cx cy'",
        f"{intr}_{stamp(2)}.pincam: missing (colour {VIDEO}_frames/lowres_wide/{VIDEO}_"
        f"{stamp(2)}.png has no intrinsics)",
        f"{VIDEO}_frames/lowres_depth/{VIDEO}_{stamp(3)}.png: missing (colour "
        f"{VIDEO}_frames/lowres_wide/{VIDEO}_{stamp(3)}.png has no depth)",
    ]


@pytest.mark.parametrize("value", ["1e999", "nan", "inf"])
def test_pincam_with_a_non_finite_number_is_named(
    rgbd_scene: RgbdScene, tmp_path: Path, value: str
) -> None:
    root = write_arkitscenes(rgbd_scene, tmp_path)
    pincam = root / f"{VIDEO}_frames" / "lowres_wide_intrinsics" / f"{VIDEO}_{stamp(0)}.pincam"
    pincam.write_text(f"{value} 12 20 22 7.5 5.5\n")
    with pytest.raises(InputError) as info:
        read_capture(root)
    assert f"{VIDEO}_{stamp(0)}.pincam: expected 6 finite numbers" in str(info.value)


def test_zip_with_options(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = write_arkitscenes(rgbd_scene, tmp_path / "cap")
    check_zip_with_options(rgbd_scene, root, "arkitscenes")


def test_validate_names_the_layout(tmp_path: Path) -> None:
    check_validate_names_layout(tmp_path, write_arkitscenes, "arkitscenes")


def test_synth_scene_as_arkitscenes(tmp_path: Path) -> None:
    """A ``dcseg synth`` capture written as ARKitScenes reads back the same."""
    check_synth_round_trip(tmp_path, write_arkitscenes, pose_atol=1e-9)
