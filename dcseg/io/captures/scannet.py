"""ScanNet export layout (what ScanNet's ``SensReader`` writes).

::

    color/<i>.jpg|png                  colour
    depth/<i>.png                      uint16 millimetres, 0 = invalid
    pose/<i>.txt                       4x4 camera-to-world, OpenCV axes
    intrinsic/intrinsic_color.txt      4x4, top-left 3x3 is K of the colour images
    intrinsic/intrinsic_depth.txt      4x4, K of the depth images (optional)

Frames are named by ``<i>`` and sorted numerically. Depth may have another resolution than
colour: it is resampled onto the colour grid with nearest neighbour, through both camera
matrices when ``intrinsic_depth.txt`` exists. Frames whose pose holds inf/NaN (ScanNet's mark for
lost tracking) are skipped with a logged warning; any other bad pose is an error.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from dcseg.config import CaptureOptions
from dcseg.errors import InputError
from dcseg.io.captures.common import (
    Camera,
    FrameSpec,
    Listing,
    missing,
    numeric_sort_key,
    read_matrix_txt,
    rel,
    warn_if_options_intrinsics,
)

__all__ = ["COLOUR_SUFFIXES", "list_frames", "matches"]

logger = logging.getLogger(__name__)

COLOUR_SUFFIXES = (".jpg", ".jpeg", ".png")
_SHOWN_SKIPPED = 5


def matches(root: Path) -> bool:
    """Whether ``root`` has ScanNet's ``color/``, ``depth/`` and ``pose/`` folders."""
    return all((root / sub).is_dir() for sub in ("color", "depth", "pose"))


def _colour_files(root: Path) -> list[Path]:
    files = [p for p in (root / "color").iterdir() if p.suffix.lower() in COLOUR_SUFFIXES]
    return sorted(files, key=lambda p: numeric_sort_key(p.stem))


def _camera(root: Path, name: str) -> NDArray[np.float64]:
    return read_matrix_txt(root / "intrinsic" / name, root)[:3, :3]


def _depth_k(root: Path) -> NDArray[np.float64] | None:
    if not (root / "intrinsic" / "intrinsic_depth.txt").is_file():
        return None
    return _camera(root, "intrinsic_depth.txt")


def list_frames(root: Path, options: CaptureOptions) -> Listing:
    """List the frames of a ScanNet export folder.

    Raises:
        InputError: the colour intrinsics file is missing or malformed.
    """
    warn_if_options_intrinsics(options, "ScanNet")
    k = _camera(root, "intrinsic_color.txt")
    source = rel(root / "intrinsic" / "intrinsic_color.txt", root)
    camera = Camera(float(k[0, 0]), float(k[1, 1]), float(k[0, 2]), float(k[1, 2]), None, source)
    depth_k = _depth_k(root)
    listing = Listing(resample_depth=True)
    skipped: list[str] = []
    for rgb in _colour_files(root):
        depth, pose = root / "depth" / f"{rgb.stem}.png", root / "pose" / f"{rgb.stem}.txt"
        if not depth.is_file():
            listing.unlist(rgb.stem, [missing(depth, root, "depth", rgb)])
        if not pose.is_file():
            listing.unlist(rgb.stem, [missing(pose, root, "pose", rgb)])
            continue
        try:
            c2w = read_matrix_txt(pose, root)
        except InputError as exc:
            listing.unlist(rgb.stem, exc.problems)
            continue
        if not np.all(np.isfinite(c2w)):
            skipped.append(rel(pose, root))
        elif depth.is_file():
            spec = FrameSpec(rgb.stem, rgb, depth, c2w, camera, rel(pose, root), depth_k=depth_k)
            listing.specs.append(spec)
    _warn_skipped(skipped)
    return listing


def _warn_skipped(skipped: list[str]) -> None:
    if not skipped:
        return
    shown = ", ".join(skipped[:_SHOWN_SKIPPED]) + (", ..." if len(skipped) > _SHOWN_SKIPPED else "")
    logger.warning(
        "skipping %d ScanNet frame(s) whose pose contains inf or NaN (tracking lost): %s",
        len(skipped),
        shown,
    )
