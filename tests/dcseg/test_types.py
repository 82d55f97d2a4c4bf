"""The shared data types validate what they hold."""

from __future__ import annotations

import numpy as np
import pytest

from dcseg.config import CaptureOptions
from dcseg.errors import InputError, Problem
from dcseg.types import Capture, Frame, Intrinsics, pose_problem
from tests.imports import loaded_after


def make_frame(name: str = "0", width: int = 8, height: int = 6, **overrides: object) -> Frame:
    fields: dict[str, object] = {
        "name": name,
        "rgb": np.zeros((height, width, 3), np.uint8),
        "depth": np.ones((height, width), np.float32),
        "intrinsics": Intrinsics(10.0, 10.0, width / 2 - 0.5, height / 2 - 0.5, width, height),
        "c2w": np.eye(4),
        "files": {"rgb": f"rgb/{name}.png", "depth": f"depth/{name}.png", "pose": "traj.txt"},
    }
    fields.update(overrides)
    return Frame(**fields)  # type: ignore[arg-type]


def test_smoke_capture_holds_frames() -> None:
    capture = Capture((make_frame("a"), make_frame("b")), layout="dcseg")
    assert len(capture) == 2
    assert capture.names == ("a", "b")
    assert capture.frame("b").name == "b"


def test_frame_arrays_are_read_only() -> None:
    frame = make_frame()
    with pytest.raises(ValueError, match="read-only"):
        frame.depth[0, 0] = 2.0


def test_exception_empty_capture() -> None:
    with pytest.raises(InputError, match="capture is empty"):
        Capture((), layout="dcseg", root="scan")


def test_exception_lists_every_problem() -> None:
    bad_pose = np.eye(4)
    bad_pose[0, 0] = 2.0
    frames = (
        make_frame("a", depth=np.ones((5, 8), np.float32)),
        make_frame("b", c2w=bad_pose),
        make_frame("b"),
    )
    with pytest.raises(InputError) as info:
        Capture(frames, layout="dcseg")
    problems = info.value.problems
    assert Problem("depth/a.png", "depth size 8x5 does not match colour size 8x6") in problems
    assert any(p.path == "traj.txt" and "not a rigid transform" in p.reason for p in problems)
    assert any("duplicate frame name 'b'" in p.reason for p in problems)
    assert len(problems) == 3


@pytest.mark.parametrize(
    ("matrix", "reason"),
    [
        (np.eye(3), "must be 4x4"),
        (np.full((4, 4), np.nan), "inf or NaN"),
        (np.diag([1.0, 1.0, -1.0, 1.0]), "reflection"),
        (np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1.0]]), "last row"),
    ],
)
def test_pose_problem_names_the_reason(matrix: np.ndarray, reason: str) -> None:
    found = pose_problem(matrix)
    assert found is not None and reason in found


def test_pose_problem_accepts_rotation() -> None:
    angle = 0.3
    pose = np.eye(4)
    pose[:2, :2] = [[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]]
    pose[:3, 3] = [1.0, 2.0, 3.0]
    assert pose_problem(pose) is None


def test_intrinsics_scaled_keeps_pixel_centres() -> None:
    k = Intrinsics(600.0, 600.0, 599.5, 339.5, 1200, 680)
    half = k.scaled(600, 340)
    assert (half.fx, half.fy) == (300.0, 300.0)
    # The image centre stays the image centre under the pixel-centre convention.
    assert (half.cx, half.cy) == (299.5, 169.5)
    expected = np.array([[300, 0, 299.5], [0, 300, 169.5], [0, 0, 1]])
    assert np.allclose(half.matrix(), expected)


def test_bad_intrinsics_and_colour_reported() -> None:
    frame = make_frame(intrinsics=Intrinsics(-1.0, 10.0, 3.5, 2.5, 4, 6))
    reasons = [p.reason for p in frame.problems()]
    assert any("intrinsics are for 4x6" in r for r in reasons)
    assert any("focal lengths" in r for r in reasons)
    grey = make_frame(rgb=np.zeros((6, 8), np.uint8))
    assert "colour must be HxWx3 uint8" in grey.problems()[0].reason


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"stride": 0}, "stride"),
        ({"max_frames": 0}, "max_frames"),
        ({"size": (0, 10)}, "size"),
        ({"depth_trunc": -1.0}, "depth_trunc"),
    ],
)
def test_capture_options_reject_bad_values(kwargs: dict[str, object], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        CaptureOptions(**kwargs)  # type: ignore[arg-type]


def test_config_does_not_import_torch() -> None:
    import subprocess
    import sys

    code = "import sys, dcseg.config, dcseg.types, dcseg.cli; assert 'torch' not in sys.modules"
    subprocess.run([sys.executable, "-c", code], check=True)


def test_cli_parser_imports_no_heavy_package() -> None:
    """``dcseg --help`` (every verb's parser) stays light: no torch, scipy, numba or httpx."""
    heavy = ("torch", "scipy", "numba", "httpx", "sklearn")
    statement = "from dcseg.cli import build_parser; build_parser()"
    assert loaded_after(statement, heavy) == []
