"""Apple ARKitScenes layout (the ``3dod`` / raw ``lowres_wide`` data of one video).

::

    [<video_id>_frames/]
      lowres_wide/<video_id>_<t>.png               colour (256x192)
      lowres_depth/<video_id>_<t>.png              uint16 millimetres, 0 = none
      lowres_wide_intrinsics/<video_id>_<t>.pincam "width height fx fy cx cy"
      lowres_wide.traj                             "t rx ry rz tx ty tz" per line
      confidence/<video_id>_<t>.png                optional: ARKit confidence 0, 1, 2

``<t>`` is the frame's timestamp in seconds with three decimals. A ``.traj`` line is a
timestamp, an axis-angle rotation (radians) and a translation (metres) of the
**world-to-camera** transform, as ARKitScenes' own loader (``tenFpsDataLoader.py``) and
nerfstudio's parser read it: ``c2w = inverse([R(r) | t])``, in OpenCV camera axes (nerfstudio
flips its y and z columns to reach OpenGL). Like those loaders, a frame takes the pose whose
timestamp is within 5 ms of its own (``CaptureOptions.sync_tolerance_ms`` changes it), and
its ``.pincam`` file may be named 1 ms off; frames without a pose (the trajectory starts
after the video or has gaps) are dropped with a warning, and a capture where no frame has one
is an error.

Frames are the ``lowres_wide`` images, named by their stem (``41069021_3052.083``) and sorted
by time. Confidence maps are read only with ``CaptureOptions.min_confidence`` > 0.
"""

from __future__ import annotations

import logging
import math
import re
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from dcseg.config import CaptureOptions
from dcseg.errors import InputError, Problem
from dcseg.io.captures.common import (
    Camera,
    FrameSpec,
    Listing,
    add_if_present,
    missing,
    rel,
    warn_if_options_intrinsics,
)

__all__ = ["TOLERANCE", "frames_folder", "list_frames", "matches"]

logger = logging.getLogger(__name__)

TOLERANCE = 0.005
"""Largest time difference (s) between a frame and its pose, as in ARKitScenes' loader."""

_TRAJ = "lowres_wide.traj"
_STEM = re.compile(r"(.+)_(\d+(?:\.\d+)?)")


def frames_folder(root: Path) -> Path | None:
    """``root`` or its one ``*_frames`` subfolder, if it holds the lowres data."""
    candidates = [root, *sorted(p for p in root.glob("*_frames") if p.is_dir())]
    for folder in candidates:
        if (folder / "lowres_wide").is_dir() and (folder / _TRAJ).is_file():
            return folder
    return None


def matches(root: Path) -> bool:
    """Whether ``root`` (or ``<video_id>_frames/`` in it) holds ``lowres_wide/`` and the traj."""
    return frames_folder(root) is not None


def _trajectory(path: Path, shown: str) -> tuple[NDArray[np.float64], list[tuple[int, str]]]:
    """Timestamps and ``(line number, values)`` of every pose line, sorted by time."""
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        raise InputError.single(shown, f"cannot read file ({exc.strerror})") from None
    rows: list[tuple[float, int, str]] = []
    for number, line in enumerate(text.splitlines(), start=1):
        values = line.split()
        if not values:
            continue
        where = f"{shown}:line {number}"
        if len(values) != 7:
            raise InputError.single(
                where, f"expected 7 values (timestamp rx ry rz tx ty tz), got {len(values)}"
            )
        try:
            numbers = [float(v) for v in values]
        except ValueError:
            raise InputError.single(where, f"values must be numbers, got {line.strip()}") from None
        if not np.all(np.isfinite(numbers)):
            raise InputError.single(where, f"values must be finite, got {line.strip()}")
        rows.append((numbers[0], number, line))
    rows.sort()
    return np.array([r[0] for r in rows], dtype=np.float64), [(r[1], r[2]) for r in rows]


def _c2w(line: str) -> NDArray[np.float64]:
    values = [float(v) for v in line.split()]
    rotation, _ = cv2.Rodrigues(np.array(values[1:4], dtype=np.float64))
    w2c = np.eye(4)
    w2c[:3, :3] = rotation
    w2c[:3, 3] = values[4:7]
    c2w = np.eye(4)
    c2w[:3, :3] = rotation.T
    c2w[:3, 3] = -rotation.T @ w2c[:3, 3]
    return c2w


def _pincam(folder: Path, video: str, stamp: float) -> Path | None:
    for offset in (0.0, -0.001, 0.001):
        path = folder / f"{video}_{stamp + offset:.3f}.pincam"
        if path.is_file():
            return path
    return None


def _camera(path: Path, root: Path) -> Camera:
    shown = rel(path, root)
    try:
        values = path.read_text(encoding="utf-8", errors="replace").split()
        width, height, fx, fy, cx, cy = (float(v) for v in values)
    except OSError as exc:
        raise InputError.single(shown, f"cannot read file ({exc.strerror})") from None
    except ValueError:
        raise InputError.single(shown, "expected 6 numbers 'width height fx fy cx cy'") from None
    if not all(map(math.isfinite, (width, height, fx, fy, cx, cy))):
        raise InputError.single(shown, f"expected 6 finite numbers, got {values}")
    if width != int(width) or height != int(height) or width < 1 or height < 1:
        raise InputError.single(shown, f"width and height must be positive integers, got {values}")
    return Camera(fx, fy, cx, cy, (int(width), int(height)), shown)


def list_frames(root: Path, options: CaptureOptions) -> Listing:
    """List the ``lowres_wide`` frames that have a pose, in time order.

    Raises:
        InputError: a malformed ``lowres_wide.traj`` line (naming it), or no frame has a pose.
    """
    folder = frames_folder(root)
    assert folder is not None
    warn_if_options_intrinsics(options, "ARKitScenes")
    ms = options.sync_tolerance_ms
    tolerance = TOLERANCE if ms is None else ms / 1000.0
    stamps, lines = _trajectory(folder / _TRAJ, rel(folder / _TRAJ, root))
    colour = [
        (m, p) for p in (folder / "lowres_wide").glob("*.png") if (m := _STEM.fullmatch(p.stem))
    ]
    listing = Listing(resample_depth=True)
    dropped: list[str] = []
    for match, rgb in sorted(colour, key=lambda mp: float(mp[0].group(2))):
        stamp = float(match.group(2))
        index = _nearest(stamps, stamp, tolerance)
        if index is None:
            dropped.append(rgb.stem)
            continue
        number, line = lines[index]
        pose_source = f"{rel(folder / _TRAJ, root)}:line {number}"
        _add(root, folder, rgb, match.group(1), stamp, _c2w(line), pose_source, listing)
    _report_dropped(dropped, len(colour), tolerance, (folder / _TRAJ, root), listing)
    return listing


def _nearest(stamps: NDArray[np.float64], stamp: float, tolerance: float) -> int | None:
    if stamps.size == 0:
        return None
    i = int(np.searchsorted(stamps, stamp))
    near = [j for j in (i - 1, i) if 0 <= j < stamps.size]
    best = min(near, key=lambda j: abs(stamps[j] - stamp))
    return best if abs(stamps[best] - stamp) <= tolerance + 1e-9 else None


def _add(
    root: Path,
    folder: Path,
    rgb: Path,
    video: str,
    stamp: float,
    c2w: NDArray[np.float64],
    pose_source: str,
    listing: Listing,
) -> None:
    pincam = _pincam(folder / "lowres_wide_intrinsics", video, stamp)
    if pincam is None:
        expected = folder / "lowres_wide_intrinsics" / f"{rgb.stem}.pincam"
        listing.unlist(rgb.stem, [missing(expected, root, "intrinsics", rgb)])
        return
    try:
        camera = _camera(pincam, root)
    except InputError as exc:
        listing.unlist(rgb.stem, exc.problems)
        return
    depth = folder / "lowres_depth" / rgb.name
    confidence = folder / "confidence" / rgb.name
    spec = FrameSpec(rgb.stem, rgb, depth, c2w, camera, pose_source, confidence=confidence)
    add_if_present(listing, spec, root)


def _report_dropped(
    dropped: list[str], total: int, tolerance: float, traj: tuple[Path, Path], listing: Listing
) -> None:
    if not dropped:
        return
    shown, ms = rel(*traj), tolerance * 1000
    if len(dropped) == total:
        listing.problems.append(Problem(shown, f"no lowres_wide frame has a pose within {ms:g} ms"))
        return
    logger.warning(
        "ARKitScenes: %d of %d frames have no pose within %g ms in %s and are dropped (first: %s)",
        len(dropped),
        total,
        ms,
        shown,
        dropped[0],
    )
