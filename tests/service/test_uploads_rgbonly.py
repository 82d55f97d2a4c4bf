"""An uploaded RGB-only COLMAP capture goes through the shared readers: accepted, its summary
saying depth is absent; without its sparse points it is a 422 naming the file."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from jobstore.settings import Settings
from service.problems import ApiProblem
from service.uploads import extract_and_validate
from tests.dcseg.io.layouts import make_scene
from tests.dcseg.io.test_captures_colmap import remove_depth, write_colmap


def zipped(folder: Path, name: Path) -> Path:
    return Path(shutil.make_archive(str(name), "zip", folder))


def test_uploaded_rgb_only_colmap_is_accepted_and_says_depth_is_absent(tmp_path: Path) -> None:
    folder = remove_depth(write_colmap(make_scene(n=3), tmp_path / "scan"))
    summary = extract_and_validate(zipped(folder, tmp_path / "ok"), tmp_path / "a", Settings())
    capture = summary["capture"]
    assert capture["layout"] == "colmap" and capture["frames"] == 3
    assert capture["depth"] == "absent (RGB-only capture)" and capture["sparse_points"] == 1
    (folder / "sparse" / "0" / "points3D.bin").unlink()
    with pytest.raises(ApiProblem) as caught:
        extract_and_validate(zipped(folder, tmp_path / "bad"), tmp_path / "b", Settings())
    assert caught.value.status == 422
    assert "sparse/0/points3D.bin: missing: an RGB-only COLMAP capture" in caught.value.detail
    assert str(tmp_path) not in caught.value.detail
