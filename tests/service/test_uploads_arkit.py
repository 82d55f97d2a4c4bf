"""Uploaded Record3D captures go through the same validation as every other upload."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from dcseg.io.lzfse_buffers import compress
from jobstore.settings import Settings
from service.problems import ApiProblem
from service.uploads import extract_and_validate
from tests.dcseg.io.test_captures_record3d import write_r3d_file, write_r3d_folder


def test_uploaded_r3d_is_a_record3d_capture_and_a_depth_bomb_is_a_422(tmp_path: Path) -> None:
    folder = write_r3d_folder(tmp_path / "scan")
    ok = extract_and_validate(
        write_r3d_file(folder, tmp_path / "ok.r3d"), tmp_path / "a", Settings()
    )
    assert ok["capture"]["layout"] == "record3d"
    assert ok["capture"]["frames"] == 3
    bomb = compress(np.zeros(12 * 9 * 1000, np.float32).tobytes())
    (folder / "rgbd" / "1.depth").write_bytes(bomb)
    bad = write_r3d_file(folder, tmp_path / "bad.r3d")
    with pytest.raises(ApiProblem) as caught:
        extract_and_validate(bad, tmp_path / "b", Settings())
    assert caught.value.status == 422
    assert "rgbd/1.depth: decompresses to more than the 432 bytes" in caught.value.detail
    assert str(tmp_path) not in caught.value.detail  # server paths stay hidden
