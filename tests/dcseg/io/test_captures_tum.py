"""TUM RGB-D layout: fixtures written per the TUM benchmark's file formats
(https://cvg.cit.tum.de/data/datasets/rgbd-dataset/file_formats)."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from dcseg.cli import main
from dcseg.config import CaptureOptions
from dcseg.errors import InputError
from dcseg.io.captures import detect_layout, read_capture, tum
from dcseg.io.images import write_image
from dcseg.types import Lens
from tests.dcseg.io.archived import check_zip_with_options
from tests.dcseg.io.layouts import (
    RgbdScene,
    assert_same_frames,
    check_validate_names_layout,
    scene_capture,
    synth_capture,
)

OPTIONS = CaptureOptions(intrinsics=(20.0, 22.0, 7.5, 5.5))
T0 = 1305031102.175304
STEP = 1 / 30


def stamps(n: int) -> list[str]:
    return [f"{T0 + i * STEP:.6f}" for i in range(n)]


def pose_line(stamp: float, c2w: np.ndarray, digits: int = 17) -> str:
    """``timestamp tx ty tz qx qy qz qw`` (world-from-camera, scalar-last quaternion)."""
    q = Rotation.from_matrix(c2w[:3, :3]).as_quat()
    values = [*c2w[:3, 3], *q]
    return f"{stamp:.4f} " + " ".join(f"{v:.{digits}g}" for v in values)


def write_tum(
    scene: RgbdScene, root: Path, depth_delay: float = 0.01, pose_delay: float = 0.003
) -> Path:
    """Colour at 30 Hz, depth ``depth_delay`` s later, poses ``pose_delay`` s later, with poses
    of other moments in between (motion capture runs faster than the camera)."""
    rgb_lines = [
        "# color images",
        "# file: 'rgbd_dataset_freiburg1_xyz.bag'",
        "# timestamp filename",
    ]
    depth_lines = [
        "# depth maps",
        "# file: 'rgbd_dataset_freiburg1_xyz.bag'",
        "# timestamp filename",
    ]
    pose_lines = ["# ground truth trajectory", "# timestamp tx ty tz qx qy qz qw"]
    for i, text in enumerate(stamps(scene.n)):
        dstamp = f"{float(text) + depth_delay:.6f}"
        write_image(root / "rgb" / f"{text}.png", scene.rgb[i])
        raw = np.rint(scene.depth[i] * tum.DEPTH_SCALE).astype(np.uint16)
        write_image(root / "depth" / f"{dstamp}.png", raw)
        rgb_lines.append(f"{text} rgb/{text}.png")
        depth_lines.append(f"{dstamp} depth/{dstamp}.png")
        pose_lines.append(pose_line(float(text) + pose_delay, scene.c2w[i]))
        pose_lines.append(pose_line(float(text) + 0.015, np.eye(4)))  # a decoy 15 ms later
    (root / "rgb.txt").write_text("\n".join(rgb_lines) + "\n")
    (root / "depth.txt").write_text("\n".join(depth_lines) + "\n")
    (root / "groundtruth.txt").write_text("\n".join(pose_lines) + "\n")
    return root


def edit_line(path: Path, number: int, text: str) -> None:
    lines = path.read_text().splitlines()
    lines[number - 1] = text
    path.write_text("\n".join(lines) + "\n")


def test_round_trip(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = write_tum(rgbd_scene, tmp_path)
    assert detect_layout(root) == "tum"
    capture = read_capture(root, OPTIONS)
    assert capture.layout == "tum" and capture.names == tuple(stamps(4))
    assert_same_frames(capture.frames, scene_capture(rgbd_scene).frames, pose_atol=1e-9)
    assert capture.frames[1].files["pose"] == "groundtruth.txt:line 5"
    assert capture.frames[1].files["depth"] == f"depth/{float(stamps(4)[1]) + 0.01:.6f}.png"


def test_published_precision_and_calibration_file(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = write_tum(rgbd_scene, tmp_path)
    lines = (root / "groundtruth.txt").read_text().splitlines()
    for number, line in enumerate(lines, start=1):  # TUM publishes 4 decimals
        if not line.startswith("#"):
            values = [float(v) for v in line.split()]
            edit_line(root / "groundtruth.txt", number, " ".join(f"{v:.4f}" for v in values))
    (root / "calibration.txt").write_text("20 22 7.5 5.5\n")
    capture = read_capture(root)
    assert capture.frames[0].files["intrinsics"] == "calibration.txt"
    assert capture.frames[0].intrinsics == rgbd_scene.k
    np.testing.assert_allclose(capture.frames[2].c2w, rgbd_scene.c2w[2], atol=2e-3)


def test_intrinsics_required(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = write_tum(rgbd_scene, tmp_path)
    with pytest.raises(InputError, match=r"no intrinsics: TUM RGB-D files store none.*freiburg3"):
        read_capture(root)
    (root / "calibration.txt").write_text("20 22 7.5\n")
    with pytest.raises(InputError, match=r"calibration\.txt: expected 4 numbers 'fx fy cx cy'"):
        read_capture(root)
    (root / "calibration.txt").write_text("20 22 7.5 5.5 0.1 0.2 0.3\n")  # 3 coefficients
    with pytest.raises(InputError, match=r"optionally followed by 4, 5 or 8 OpenCV distortion"):
        read_capture(root)


FREIBURG1 = (0.2624, -0.9531, -0.0054, 0.0026, 1.1633)  # TUM's published d0..d4


def test_distortion_from_calibration_file_or_options(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    """freiburg1/2 images are distorted: ``d0..d4`` (OpenCV's k1 k2 p1 p2 k3) after the
    intrinsics in calibration.txt, or --distortion beside --intrinsics."""
    root = write_tum(rgbd_scene, tmp_path)
    (root / "calibration.txt").write_text("20 22 7.5 5.5 " + " ".join(map(str, FREIBURG1)))
    frame = read_capture(root).frames[0]
    assert frame.undistortion is not None
    assert frame.undistortion.lens == Lens("opencv", FREIBURG1, "calibration.txt")
    assert frame.undistortion.source == rgbd_scene.k and frame.intrinsics != rgbd_scene.k
    (root / "calibration.txt").unlink()
    options = CaptureOptions(intrinsics=(20.0, 22.0, 7.5, 5.5), distortion=FREIBURG1)
    same = read_capture(root, options).frames[0]
    assert same.undistortion is not None
    assert same.undistortion.lens == Lens("opencv", FREIBURG1, "CaptureOptions.distortion")
    assert same.intrinsics == frame.intrinsics
    np.testing.assert_array_equal(same.rgb, frame.rgb)


@pytest.mark.parametrize(
    ("fields", "reason"),
    [
        ({"distortion": FREIBURG1}, "distortion is the lens of intrinsics: give intrinsics too"),
        (
            {"intrinsics": (20.0, 22.0, 7.5, 5.5), "distortion": (0.1, 0.2, 0.3)},
            "distortion must be 4, 5 or 8 numbers (k1,k2,p1,p2[,k3[,k4,k5,k6]]), got 3",
        ),
    ],
)
def test_distortion_option_checked(fields: dict[str, object], reason: str) -> None:
    with pytest.raises(ValueError) as info:
        CaptureOptions(**fields)  # type: ignore[arg-type]
    assert str(info.value) == reason


def test_no_depth_within_tolerance(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = write_tum(rgbd_scene, tmp_path)
    lines = (root / "depth.txt").read_text().splitlines()
    (root / "depth.txt").write_text("\n".join(lines[:4] + lines[5:]) + "\n")
    with pytest.raises(InputError) as info:
        read_capture(root, OPTIONS)
    assert [str(p) for p in info.value.problems] == [
        f"rgb.txt:line 5: timestamp {stamps(4)[1]}: no depth image in depth.txt within 20 ms "
        "(the nearest is 23.3 ms away)"
    ]
    options = CaptureOptions(intrinsics=OPTIONS.intrinsics, sync_tolerance_ms=25)
    assert read_capture(root, options).names == tuple(stamps(4))


def test_tolerance_is_a_job_option_and_a_flag(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    from dcseg.cli._options import add_groups, capture_options
    from dcseg.options import build_config, parse_options

    root = write_tum(rgbd_scene, tmp_path)
    for bad in (0, -5, 1001, "x"):
        with pytest.raises(InputError) as caught:
            parse_options({"capture": {"sync_tolerance_ms": bad}})
        assert [p.path for p in caught.value.problems] == ["options.capture.sync_tolerance_ms"]
    job = parse_options({"capture": {"sync_tolerance_ms": 2, "intrinsics": [20, 22, 7.5, 5.5]}})
    with pytest.raises(InputError, match=r"no depth image in depth\.txt within 2 ms"):
        read_capture(root, build_config("fast", job).capture)
    parser = argparse.ArgumentParser()
    add_groups(parser, "capture")
    args = parser.parse_args(["--sync-tolerance-ms", "2", "--intrinsics", "20,22,7.5,5.5"])
    assert capture_options(args).sync_tolerance_ms == 2.0


def test_pose_line_with_seven_values(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = write_tum(rgbd_scene, tmp_path)
    path = root / "groundtruth.txt"
    edit_line(path, 5, " ".join(path.read_text().splitlines()[4].split()[:7]))
    with pytest.raises(InputError) as info:
        read_capture(root, OPTIONS)
    problems = [str(p) for p in info.value.problems]
    assert problems[0] == (
        "groundtruth.txt:line 5: expected 8 values (timestamp tx ty tz qx qy qz qw), got 7"
    )
    # frame 1 now pairs with the 15 ms decoy: nothing else is wrong
    assert len(problems) == 1


def test_bad_pose_values(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = write_tum(rgbd_scene, tmp_path)
    stamp = float(stamps(4)[2]) + 0.003
    edit_line(root / "groundtruth.txt", 7, f"{stamp:.4f} 0 0 0 0.5 0.5 0.5 0.2")
    edit_line(root / "groundtruth.txt", 3, f"{T0 + 0.003:.4f} 0 0 x 0 0 0 1")
    edit_line(root / "rgb.txt", 5, f"nan rgb/{stamps(4)[1]}.png")
    with pytest.raises(InputError) as info:
        read_capture(root, OPTIONS)
    assert [str(p) for p in info.value.problems] == [
        "rgb.txt:line 5: timestamp 'nan' is not a number",
        f"groundtruth.txt:line 3: timestamp {T0 + 0.003:.4f}: pose values must be numbers "
        "(timestamp tx ty tz qx qy qz qw)",
        f"groundtruth.txt:line 7: timestamp {stamp:.4f}: quaternion (qx, qy, qz, qw) has norm "
        "0.888819, expected 1",
    ]


def test_frames_outside_the_ground_truth_are_dropped(
    rgbd_scene: RgbdScene, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    root = write_tum(rgbd_scene, tmp_path)
    lines = (root / "groundtruth.txt").read_text().splitlines()
    (root / "groundtruth.txt").write_text("\n".join(lines[:2] + lines[4:]) + "\n")
    with caplog.at_level(logging.WARNING):
        capture = read_capture(root, OPTIONS)
    assert capture.names == tuple(stamps(4)[1:])
    assert "1 of 4 colour frames lie outside the time span of groundtruth.txt" in caplog.text
    (root / "groundtruth.txt").write_text("# nothing yet\n")
    with pytest.raises(InputError, match=r"groundtruth\.txt: no colour frame lies within"):
        read_capture(root, OPTIONS)


def test_gap_in_the_ground_truth(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = write_tum(rgbd_scene, tmp_path)
    lines = (root / "groundtruth.txt").read_text().splitlines()
    (root / "groundtruth.txt").write_text("\n".join(lines[:3] + lines[6:]) + "\n")
    with pytest.raises(InputError) as info:
        read_capture(root, OPTIONS)
    assert [str(p) for p in info.value.problems] == [
        f"rgb.txt:line 5: timestamp {stamps(4)[1]}: no pose in groundtruth.txt within 20 ms "
        "(the nearest is 30.3 ms away)"
    ]


def test_file_name_with_a_nul_byte_is_named(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = write_tum(rgbd_scene, tmp_path)
    edit_line(root / "rgb.txt", 4, f"{stamps(4)[0]} rgb/a\0b.png")
    with pytest.raises(InputError) as info:
        read_capture(root, OPTIONS)
    assert [str(p) for p in info.value.problems] == [
        "rgb.txt:line 4: path 'rgb/a\\x00b.png' must be relative to and inside the capture"
    ]


def test_missing_files_and_escaping_paths(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    root = write_tum(rgbd_scene, tmp_path)
    edit_line(root / "rgb.txt", 4, f"{stamps(4)[0]} ../outside.png")
    (root / "rgb" / f"{stamps(4)[1]}.png").unlink()
    with pytest.raises(InputError) as info:
        read_capture(root, OPTIONS)
    assert [str(p) for p in info.value.problems] == [
        "rgb.txt:line 4: path '../outside.png' must be relative to and inside the capture",
        f"rgb/{stamps(4)[1]}.png: missing (colour rgb/{stamps(4)[1]}.png has no colour)",
    ]
    (root / "groundtruth.txt").unlink()
    with pytest.raises(InputError, match=r"groundtruth\.txt: missing: TUM captures need poses"):
        read_capture(root, OPTIONS)


def test_zip_with_options(rgbd_scene: RgbdScene, tmp_path: Path) -> None:
    check_zip_with_options(rgbd_scene, write_tum(rgbd_scene, tmp_path / "cap"), "tum")


def test_validate_names_the_layout(tmp_path: Path) -> None:
    check_validate_names_layout(tmp_path, write_tum, "tum", OPTIONS)


def test_synth_scene_as_tum(tmp_path: Path) -> None:
    """A ``dcseg synth`` capture written as TUM reads back with its poses, intrinsics, depth."""
    original = synth_capture(tmp_path / "s")
    scene = RgbdScene(
        [f.rgb for f in original.frames],
        [
            np.rint(f.depth * tum.DEPTH_SCALE).astype(np.float32) / tum.DEPTH_SCALE
            for f in original.frames
        ],
        [f.c2w for f in original.frames],
        original.frames[0].intrinsics,
    )
    root = write_tum(scene, tmp_path / "tum")
    k = scene.k
    capture = read_capture(root, CaptureOptions(intrinsics=(k.fx, k.fy, k.cx, k.cy)))
    assert len(capture) == 6
    depth_atol = 0.5 / tum.DEPTH_SCALE + 1e-6
    assert_same_frames(capture.frames, original.frames, pose_atol=1e-9, depth_atol=depth_atol)


def test_validate_names_the_lens_given_on_the_command_line(
    rgbd_scene: RgbdScene, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    root = write_tum(rgbd_scene, tmp_path)
    flags = ["--intrinsics", "20,22,7.5,5.5", "--distortion", ",".join(map(str, FREIBURG1))]
    assert main(["validate", str(root), *flags]) == 0
    assert (
        "undistorted: 4 frame(s) through the opencv lens (0.2624 -0.9531 -0.0054 0.0026 1.1633) "
        "of CaptureOptions.distortion" in capsys.readouterr().out
    )
    with pytest.raises(SystemExit):
        main(["validate", str(root), "--intrinsics", "20,22,7.5,5.5", "--distortion", "a,b"])
    assert "--distortion: expected comma-separated numbers" in capsys.readouterr().err
