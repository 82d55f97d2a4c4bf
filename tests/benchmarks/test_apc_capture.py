"""apc_capture: the APC shelf sample's depth and poses as dcseg reads them."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from benchmarks.apc_capture import convert, depth_mm, poses, vocabulary
from dcseg.config import CaptureOptions
from dcseg.io.captures import read_capture


def _shifted(metres: np.ndarray) -> np.ndarray:
    """The sample's encoding (rgbd-utils/matlab/writeDepth.m): 1/10000 m, 3-bit rotation."""
    v = np.round(metres * 10000).astype(np.uint32)
    return (((v << 3) | (v >> 13)) & 0xFFFF).astype(np.uint16)


INFO = """# Color camera intrinsic matrix
 1 0 0

# Camera-to-world extrinsic matrix (camera pose) for frame-000000
 1 0 0 0.5
 0 1 0 0
 0 0 1 1
 0 0 0 1

# Camera-to-world extrinsic matrix (camera pose) for frame-000001
 0 -1 0 0
 1 0 0 0.25
 0 0 1 1
 0 0 0 1
"""


def test_depth_decodes_to_millimetres() -> None:
    metres = np.array([[0.0, 0.5, 1.234, 6.5]])
    assert depth_mm(_shifted(metres)).tolist() == [[0, 500, 1234, 6500]]


def test_poses_and_vocabulary() -> None:
    found = poses(INFO)
    assert list(found) == ["frame-000000", "frame-000001"]
    assert found["frame-000001"][:2, :2].tolist() == [[0.0, -1.0], [1.0, 0.0]]
    names = vocabulary({8: "stems", 24: "book"})
    assert len(names) == 145 and names[48] == "stems" and names[144] == "book"


def test_converted_capture_reads_as_7scenes(tmp_path: Path) -> None:
    scene, out = tmp_path / "scene", tmp_path / "out"
    scene.mkdir()
    (scene / "cam.info.txt").write_text(INFO)
    depth = np.full((48, 64), 0.8)
    for name in ("frame-000000", "frame-000001"):
        cv2.imwrite(str(scene / f"{name}.color.png"), np.zeros((48, 64, 3), np.uint8))
        cv2.imwrite(str(scene / f"{name}.depth.png"), _shifted(depth))
    assert convert(scene, out) == 2
    capture = read_capture(out, CaptureOptions(intrinsics=(50.0, 50.0, 32.0, 24.0)))
    assert capture.layout == "7scenes" and len(capture) == 2
    assert np.allclose(capture.frames[0].depth, 0.8)
    assert np.allclose(capture.frames[1].c2w[:3, 3], [0.0, 0.25, 1.0])
