"""Microsoft 7-Scenes layout.

::

    frame-NNNNNN.color.png|jpg     colour
    frame-NNNNNN.depth.png         uint16 millimetres; 0 and 65535 = invalid
    frame-NNNNNN.pose.txt          4x4 camera-to-world

Files sit in the capture folder or in its immediate subfolders (``seq-01/`` ...). Frames are
named by the stem without the part suffix, keeping the subfolder: ``frame-000000`` or
``seq-01/frame-000000``; they are ordered by subfolder, then frame number. 7-Scenes stores no
intrinsics: they come from ``CaptureOptions.intrinsics``; without it, 640x480 images get the
usual Kinect values (fx = fy = 585, cx = 320, cy = 240, logged) and other sizes are an error.
"""

from __future__ import annotations

import logging
import re
from pathlib import Path

from dcseg.config import CaptureOptions
from dcseg.errors import InputError, Problem
from dcseg.io.captures.common import (
    Camera,
    FrameSpec,
    Listing,
    missing,
    numeric_sort_key,
    options_camera,
    read_matrix_txt,
    rel,
)
from dcseg.io.images import image_size, read_image

__all__ = ["DEFAULT_INTRINSICS", "list_frames", "matches"]

logger = logging.getLogger(__name__)

DEFAULT_INTRINSICS = (585.0, 585.0, 320.0, 240.0)
"""The commonly used 7-Scenes Kinect intrinsics ``(fx, fy, cx, cy)`` for 640x480 images."""

_DEFAULT_SIZE = (640, 480)
_COLOUR = re.compile(r"(frame-\d+)\.color\.(png|jpg|jpeg)", re.IGNORECASE)
_INVALID_DEPTH = (65535,)


def _colour_files(folder: Path) -> list[Path]:
    return [p for p in folder.iterdir() if _COLOUR.fullmatch(p.name)]


def _folders(root: Path) -> list[Path]:
    subfolders = sorted(p for p in root.iterdir() if p.is_dir())
    return [root, *subfolders]


def matches(root: Path) -> bool:
    """Whether ``root`` or one of its subfolders holds ``frame-*.color.*`` files."""
    return any(_colour_files(folder) for folder in _folders(root))


def _colour_in_order(root: Path) -> list[Path]:
    out: list[Path] = []
    for folder in _folders(root):
        out.extend(sorted(_colour_files(folder), key=lambda p: numeric_sort_key(_stem(p))))
    return out


def _stem(path: Path) -> str:
    match = _COLOUR.fullmatch(path.name)
    return match.group(1) if match else path.stem


def _camera(root: Path, first: Path | None, options: CaptureOptions) -> Camera:
    camera = options_camera(options)
    if camera is not None or first is None:
        return camera or Camera(*DEFAULT_INTRINSICS, _DEFAULT_SIZE, "7-Scenes defaults")
    size = image_size(first)
    if size is None:
        image = read_image(first, root=root)
        size = (int(image.shape[1]), int(image.shape[0]))
    if size != _DEFAULT_SIZE:
        raise InputError.single(
            rel(first, root),
            f"7-Scenes images of {size[0]}x{size[1]} need explicit intrinsics: pass "
            "CaptureOptions(intrinsics=(fx, fy, cx, cy)) (defaults exist only for 640x480)",
        )
    logger.info("7-Scenes: using the default Kinect intrinsics fx=fy=585, cx=320, cy=240")
    return Camera(*DEFAULT_INTRINSICS, _DEFAULT_SIZE, "7-Scenes default intrinsics")


def list_frames(root: Path, options: CaptureOptions) -> Listing:
    """List the frames of a 7-Scenes folder (root files first, then each subfolder).

    Raises:
        InputError: no intrinsics were given and the images are not 640x480.
    """
    colour = _colour_in_order(root)
    camera = _camera(root, colour[0] if colour else None, options)
    listing = Listing()
    for rgb in colour:
        spec = _spec(root, rgb, camera, listing.problems)
        if spec is not None:
            listing.specs.append(spec)
        else:
            listing.unlisted.append(rel(rgb.with_name(_stem(rgb)), root))
    return listing


def _spec(root: Path, rgb: Path, camera: Camera, problems: list[Problem]) -> FrameSpec | None:
    stem = _stem(rgb)
    depth = rgb.with_name(f"{stem}.depth.png")
    pose = rgb.with_name(f"{stem}.pose.txt")
    has_depth = _present(depth, "depth", root, rgb, problems)
    has_pose = _present(pose, "pose", root, rgb, problems)
    if not (has_depth and has_pose):
        return None
    try:
        c2w = read_matrix_txt(pose, root)
    except InputError as exc:
        problems.extend(exc.problems)
        return None
    name = rel(rgb.with_name(stem), root)
    return FrameSpec(name, rgb, depth, c2w, camera, rel(pose, root), depth_invalid=_INVALID_DEPTH)


def _present(path: Path, part: str, root: Path, rgb: Path, problems: list[Problem]) -> bool:
    if path.is_file():
        return True
    problems.append(missing(path, root, part, rgb))
    return False
