"""PLY files from elsewhere: an element count the file cannot hold is refused before plyfile
allocates it; what plyfile raises is named."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import plyfile
import pytest
import torch

from dcseg.errors import InputError
from dcseg.gaussians import Gaussians
from dcseg.io.ground_truth import read_ground_truth
from dcseg.io.ply import read_gaussians_ply, write_gaussians_ply


def ground_truth(path: Path, text: bool) -> Path:
    points = np.zeros(20, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("label", "i4")])
    points["x"] = np.arange(20)
    points["label"] = np.arange(20) % 3
    plyfile.PlyData([plyfile.PlyElement.describe(points, "vertex")], text=text).write(str(path))
    return path


def replace_once(path: Path, old: bytes, new: bytes) -> Path:
    data = path.read_bytes()
    assert old in data
    path.write_bytes(data.replace(old, new, 1))
    return path


@pytest.mark.parametrize("text", [True, False])
def test_vertex_count_the_file_cannot_hold_is_refused(tmp_path: Path, text: bool) -> None:
    path = ground_truth(tmp_path / "gt.ply", text)
    replace_once(path, b"element vertex 20", b"element vertex 99999999999")
    row = 8 if text else 16
    with pytest.raises(InputError) as info:
        read_ground_truth(path, 3)
    assert str(info.value).startswith(
        f"gt.ply: not a readable PLY file: its header declares rows of at least "
        f"{99999999999 * row:,} bytes, the file holds "
    )


def flat_gaussians(n: int) -> Gaussians:
    """``n`` unit Gaussians at the origin (what a PLY test needs to write)."""
    return Gaussians(
        torch.zeros(n, 3), torch.tensor([[1.0, 0, 0, 0]] * n), torch.zeros(n, 3), torch.zeros(n),
        torch.zeros(n, 1, 3),
    )  # fmt: skip


def test_scene_ply_with_an_inflated_count_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "scene.ply"
    write_gaussians_ply(path, flat_gaussians(5))
    replace_once(path, b"element vertex 5", b"element vertex 4000000000")
    with pytest.raises(InputError, match="its header declares rows of at least"):
        read_gaussians_ply(path)


def test_ascii_value_beyond_its_type_is_named(tmp_path: Path) -> None:
    path = ground_truth(tmp_path / "gt.ply", text=True)
    lines = path.read_bytes().split(b"\n")
    at = lines.index(b"end_header") + 2
    lines[at] = lines[at].rsplit(b" ", 1)[0] + b" 99999999999"
    path.write_bytes(b"\n".join(lines))
    with pytest.raises(InputError, match=r"^gt\.ply: not a readable PLY file \("):
        read_ground_truth(path, 3)
