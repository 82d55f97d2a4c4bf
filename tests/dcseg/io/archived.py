"""One check every layout added for issue 39 shares: read from a zip with every capture option."""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np

from dcseg.config import CaptureOptions
from dcseg.io import images
from dcseg.io.captures import read_capture
from tests.dcseg.io.layouts import RgbdScene


def check_zip_with_options(scene: RgbdScene, root: Path, layout: str) -> None:
    """``root`` zipped under a top folder reads as ``layout``: stride, max_frames, size and
    depth_trunc applied (intrinsics scaled, depth resampled by nearest neighbour)."""
    archive = root.parent / f"{root.name}.zip"
    with zipfile.ZipFile(archive, "w") as zf:
        for path in sorted(root.rglob("*")):
            zf.write(path, "scan/" + path.relative_to(root).as_posix())
    options = CaptureOptions(
        stride=2, max_frames=1, size=(8, 6), depth_trunc=2.0, intrinsics=(20.0, 22.0, 7.5, 5.5)
    )
    capture = read_capture(archive, options)
    assert capture.layout == layout and len(capture) == 1 and capture.root == str(archive)
    frame = capture.frames[0]
    assert frame.rgb.shape == (6, 8, 3) and frame.intrinsics == scene.k.scaled(8, 6)
    expected = images.resize_nearest(scene.depth[0], (8, 6))
    np.testing.assert_allclose(frame.depth, np.where(expected > 2.0, 0.0, expected), atol=2e-4)
    np.testing.assert_allclose(frame.c2w, scene.c2w[0], atol=1e-9)
