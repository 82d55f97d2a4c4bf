"""Polycam's raw data export (LiDAR captures, "Export raw data" in the app).

::

    keyframes/images/<t>.jpg                colour
    keyframes/cameras/<t>.json              {"fx", "fy", "cx", "cy", "width", "height",
                                             "t_00" .. "t_23", ...}
    keyframes/corrected_images/<t>.jpg      optional: images and cameras after Polycam's
    keyframes/corrected_cameras/<t>.json        pose optimisation (used when both exist)
    keyframes/depth/<t>.png                 uint16 millimetres, 0 = none (LiDAR resolution)
    keyframes/confidence/<t>.png            uint8 ARKit confidence 0 (low) .. 2 (high)

``fx fy cx cy`` are pixels of the ``width x height`` colour image. ``t_ij`` is row ``i``,
column ``j`` of the 3x4 ARKit camera-to-world pose, converted to OpenCV camera axes as described
in :mod:`dcseg.io.captures.arkit` (the world stays ARKit's, y up). Depth has its own resolution
and is resampled onto the colour grid with nearest neighbour; confidence is read only with
``CaptureOptions.min_confidence`` > 0. Frames are named by the timestamp stem ``<t>`` and sorted
numerically. Other camera keys (``blur_score``, ``timestamp``, ...) are not used.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np

from dcseg.config import CaptureOptions
from dcseg.errors import InputError, Problem
from dcseg.io.captures.arkit import opencv_pose
from dcseg.io.captures.common import (
    Camera,
    FrameSpec,
    Listing,
    add_if_present,
    missing,
    numeric_sort_key,
    rel,
    warn_if_options_intrinsics,
)
from dcseg.io.captures.jsonfields import JsonFields, load_json
from dcseg.io.captures.scannet import COLOUR_SUFFIXES

__all__ = ["KEYFRAMES", "list_frames", "matches"]

logger = logging.getLogger(__name__)

KEYFRAMES = "keyframes"
_PLAIN = ("images", "cameras")
_CORRECTED = ("corrected_images", "corrected_cameras")
_POSE_KEYS = tuple(f"t_{row}{col}" for row in range(3) for col in range(4))


def matches(root: Path) -> bool:
    """Whether ``root`` has ``keyframes/`` with images and cameras (plain or corrected)."""
    keyframes = root / KEYFRAMES
    return any(all((keyframes / sub).is_dir() for sub in pair) for pair in (_CORRECTED, _PLAIN))


def _folders(root: Path) -> tuple[Path, Path]:
    keyframes = root / KEYFRAMES
    if all((keyframes / sub).is_dir() for sub in _CORRECTED):
        logger.info("Polycam: using keyframes/corrected_images and corrected_cameras")
        return keyframes / _CORRECTED[0], keyframes / _CORRECTED[1]
    return keyframes / _PLAIN[0], keyframes / _PLAIN[1]


def _camera_json(path: Path, root: Path) -> tuple[Camera, np.ndarray[Any, Any]]:
    """The intrinsics and OpenCV camera-to-world pose of one camera file.

    Raises:
        InputError: every missing or malformed field.
    """
    shown = rel(path, root)
    fields = JsonFields(shown)
    doc = fields.mapping(load_json(path, shown), "")
    if doc is None:
        raise InputError(fields.problems)
    fx, fy, cx, cy = (fields.number(doc, key, "") for key in ("fx", "fy", "cx", "cy"))
    width, height = fields.integer(doc, "width", ""), fields.integer(doc, "height", "")
    pose = [fields.number(doc, key, "") for key in _POSE_KEYS]
    fields.raise_if_any()
    assert fx is not None and fy is not None and cx is not None and cy is not None
    assert width is not None and height is not None
    arkit = np.eye(4)
    arkit[:3, :] = np.array(pose, dtype=np.float64).reshape(3, 4)
    return Camera(fx, fy, cx, cy, (width, height), shown), opencv_pose(arkit)


def list_frames(root: Path, options: CaptureOptions) -> Listing:
    """List the frames of a Polycam raw data folder.

    Missing or malformed camera files are reported per frame (every problem at once).
    """
    warn_if_options_intrinsics(options, "Polycam")
    images, cameras = _folders(root)
    colour = [p for p in images.iterdir() if p.suffix.lower() in COLOUR_SUFFIXES]
    listing = Listing(resample_depth=True)
    for rgb in sorted(colour, key=lambda p: numeric_sort_key(p.stem)):
        spec = _spec(root, rgb, cameras / f"{rgb.stem}.json", listing.problems)
        if spec is None:
            listing.unlisted.append(rgb.stem)
        else:
            add_if_present(listing, spec, root)
    return listing


def _spec(root: Path, rgb: Path, camera_file: Path, problems: list[Problem]) -> FrameSpec | None:
    if not camera_file.is_file():
        problems.append(missing(camera_file, root, "camera", rgb))
        return None
    try:
        camera, c2w = _camera_json(camera_file, root)
    except InputError as exc:
        problems.extend(exc.problems)
        return None
    keyframes = root / KEYFRAMES
    return FrameSpec(
        rgb.stem,
        rgb,
        keyframes / "depth" / f"{rgb.stem}.png",
        c2w,
        camera,
        rel(camera_file, root),
        confidence=keyframes / "confidence" / f"{rgb.stem}.png",
    )
