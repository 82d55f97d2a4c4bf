"""Image sizes from file headers, so pixel budgets apply before decoding (issue 17, defect 1)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from dcseg.io.images import header_pixels, image_size


@pytest.mark.parametrize("suffix", [".png", ".jpg", ".tif"])
def test_image_size_read_from_headers(tmp_path: Path, suffix: str) -> None:
    """Defect 1: sizes come from PNG, JPEG and TIFF headers, so budgets apply before decoding."""
    path = tmp_path / f"a{suffix}"
    assert cv2.imwrite(str(path), np.zeros((12, 16, 3), np.uint8))
    assert image_size(path) == (16, 12)
    assert header_pixels(path) == 192
    np.save(tmp_path / "d.npy", np.zeros((5, 7), np.float32))
    assert header_pixels(tmp_path / "d.npy") == 35
    (tmp_path / "junk.png").write_bytes(b"junk")
    assert header_pixels(tmp_path / "junk.png") is None
