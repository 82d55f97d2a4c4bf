"""ScanNet++ iPhone layout (after the ScanNet++ toolkit extracted the frames).

::

    [iphone/]
      rgb/frame_NNNNNN.jpg          colour (1920x1440), extracted from rgb.mkv / rgb.mp4
      depth/frame_NNNNNN.png        uint16 millimetres (256x192), extracted from depth.bin
      pose_intrinsic_imu.json       {"frame_NNNNNN": {"aligned_pose": 4x4, "intrinsic": 3x3, ...}}

``aligned_pose`` is the ARKit pose registered to the laser scan (the frame the scan's meshes and
annotations live in), camera-to-world with OpenCV camera axes (x right, y down, z forward:
nerfstudio-style parsers of this file flip its y and z columns to reach OpenGL), metres; it is
used as it is. ``pose`` (the raw ARKit pose, in ARKit's own world) and ``imu`` are not used.
``intrinsic`` is the 3x3 camera matrix of the colour image. Depth, registered to the colour
camera at the LiDAR resolution, is resampled onto the colour grid (nearest).

The folder is the ``iphone/`` folder or the scene folder holding it. Frames are the extracted
colour images (the toolkit may keep every n-th), named by their stem (``frame_000120``) in
frame order; each needs its entry in the JSON and its depth image. The video and ``depth.bin``
themselves are not read: extract the frames first with the toolkit.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from dcseg.config import CaptureOptions
from dcseg.errors import InputError, Problem
from dcseg.io.captures.common import (
    Camera,
    FrameSpec,
    Listing,
    add_if_present,
    numeric_sort_key,
    rel,
    warn_if_options_intrinsics,
)
from dcseg.io.captures.jsonfields import JsonFields, load_json

__all__ = ["POSES", "iphone_folder", "list_frames", "matches"]

POSES = "pose_intrinsic_imu.json"
"""The per-frame pose and intrinsics file of a ScanNet++ iPhone capture."""

_COLOUR_SUFFIXES = {".jpg", ".jpeg", ".png"}


def iphone_folder(root: Path) -> Path | None:
    """``root`` or ``root/iphone`` if it holds ``rgb/`` and ``pose_intrinsic_imu.json``."""
    for folder in (root, root / "iphone"):
        if (folder / "rgb").is_dir() and (folder / POSES).is_file():
            return folder
    return None


def matches(root: Path) -> bool:
    """Whether ``root`` (or its ``iphone/``) holds ``rgb/`` and ``pose_intrinsic_imu.json``."""
    return iphone_folder(root) is not None


def _intrinsics(fields: JsonFields, entry: dict[str, Any], name: str, shown: str) -> Camera | None:
    k = fields.matrix3(entry, "intrinsic", name)
    if k is None:
        return None
    return Camera(k[0, 0], k[1, 1], k[0, 2], k[1, 2], None, f"{shown}:{name}.intrinsic")


def list_frames(root: Path, options: CaptureOptions) -> Listing:
    """List the extracted colour frames that have an entry in ``pose_intrinsic_imu.json``.

    Raises:
        InputError: the JSON file is unreadable or not an object.
    """
    folder = iphone_folder(root)
    assert folder is not None
    warn_if_options_intrinsics(options, "ScanNet++")
    shown = rel(folder / POSES, root)
    fields = JsonFields(shown)
    doc = fields.mapping(load_json(folder / POSES, shown), "")
    if doc is None:
        raise InputError(fields.problems)
    colour = [p for p in (folder / "rgb").iterdir() if p.suffix.lower() in _COLOUR_SUFFIXES]
    listing = Listing(resample_depth=True)
    for rgb in sorted(colour, key=lambda p: numeric_sort_key(p.stem)):
        spec = _spec(folder, rgb, doc, fields, shown)
        listing.problems.extend(fields.problems)
        fields.problems.clear()
        if spec is None:
            listing.unlisted.append(rgb.stem)
        else:
            add_if_present(listing, spec, root)
    return listing


def _spec(
    folder: Path, rgb: Path, doc: dict[str, Any], fields: JsonFields, shown: str
) -> FrameSpec | None:
    name = rgb.stem
    if name not in doc:
        fields.problems.append(
            Problem(shown, f"{name}: missing (colour rgb/{rgb.name} has no entry)")
        )
        return None
    entry = fields.mapping(doc[name], name)
    if entry is None:
        return None
    camera = _intrinsics(fields, entry, name, shown)
    c2w = fields.matrix4(entry, "aligned_pose", name)
    if camera is None or c2w is None:
        return None
    depth = folder / "depth" / f"{name}.png"
    return FrameSpec(name, rgb, depth, c2w, camera, f"{shown}:{name}.aligned_pose")
