"""TUM RGB-D benchmark layout (and TUM-format captures such as ETH3D SLAM's).

::

    rgb.txt           "timestamp filename" per line (``#`` comments), colour images
    depth.txt         "timestamp filename" per line, uint16 PNG depth, value / 5000 = metres
    groundtruth.txt   "timestamp tx ty tz qx qy qz qw": the colour camera's optical centre and
                      orientation (scalar-last unit quaternion) in the world: camera-to-world
    calibration.txt   optional (ETH3D's TUM-format datasets): "fx fy cx cy", optionally
                      followed by OpenCV's distortion "k1 k2 p1 p2 [k3 [k4 k5 k6]]"

Timestamps are seconds. Each colour frame is associated with the depth image and the pose
nearest in time (TUM's ``associate.py`` with its default ``max_difference`` of 20 ms; the
tolerance is ``CaptureOptions.sync_tolerance_ms``, flag ``--sync-tolerance-ms``). TUM's camera
frame is the optical one (x right, y down, z forward: OpenCV's), so poses are used as they
are.

What happens to a colour frame without a match within the tolerance:

* no depth image: an error naming ``rgb.txt``, the line and the timestamp (the Kinect records
  colour and depth together, so a gap means missing data);
* no pose, while the frame lies *outside* the time span of ``groundtruth.txt`` (the
  motion-capture recording started late or stopped early, common in TUM sequences): the frame
  is dropped with a warning;
* no pose *inside* that span (a gap in the ground truth): an error naming the line.

Frames are named by their colour timestamp as written in ``rgb.txt`` (``1305031102.175304``).
TUM stores no intrinsics: they come from ``calibration.txt`` or ``CaptureOptions.intrinsics``
(with ``CaptureOptions.distortion`` for freiburg1 and 2, whose images are distorted; frames and
masks are then undistorted when read, :mod:`dcseg.lens`).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from dcseg.config import CaptureOptions
from dcseg.errors import InputError, Problem
from dcseg.io.captures.arkit import quaternion_pose
from dcseg.io.captures.common import (
    Camera,
    FrameSpec,
    Listing,
    add_if_present,
    options_camera,
    warn_if_options_intrinsics,
)
from dcseg.io.folders import inside
from dcseg.types import Lens

__all__ = ["DEPTH_SCALE", "TOLERANCE", "list_frames", "matches"]

logger = logging.getLogger(__name__)

DEPTH_SCALE = 5000.0
"""TUM's depth scale: a stored 16-bit value / 5000 = metres (0 = no depth)."""
TOLERANCE = 0.02
"""Largest time difference (s) between a colour frame and its depth image or pose."""

RGB, DEPTH, POSES, CALIBRATION = "rgb.txt", "depth.txt", "groundtruth.txt", "calibration.txt"
_POSE_FIELDS = "timestamp tx ty tz qx qy qz qw"
_NO_INTRINSICS = (
    "no intrinsics: TUM RGB-D files store none; pass CaptureOptions(intrinsics=(fx, fy, cx, cy), "
    "distortion=(k1, k2, p1, p2, k3)) (--intrinsics, --distortion) or add calibration.txt "
    "('fx fy cx cy [k1 k2 p1 p2 k3]'). TUM's published colour calibrations are freiburg1 517.3 "
    "516.5 318.6 255.3 with distortion 0.2624 -0.9531 -0.0054 0.0026 1.1633, freiburg2 520.9 "
    "521.0 325.1 249.7 with 0.2312 -0.7849 -0.0033 -0.0001 0.9172, freiburg3 535.4 539.2 320.1 "
    "247.6 (undistorted)"
)


@dataclass(frozen=True)
class _Row:
    """One data line of a TUM text file."""

    stamp: float
    text: str  # the timestamp as written (frame names keep it exactly)
    line: int
    values: tuple[str, ...]


def matches(root: Path) -> bool:
    """Whether ``root`` holds TUM's ``rgb.txt`` and ``depth.txt``."""
    return (root / RGB).is_file() and (root / DEPTH).is_file()


def _lines(root: Path, name: str) -> list[str]:
    try:
        return (root / name).read_text(encoding="utf-8", errors="replace").splitlines()
    except FileNotFoundError:
        raise InputError.single(name, "missing") from None
    except OSError as exc:
        raise InputError.single(name, f"cannot read file ({exc.strerror})") from None


def _table(root: Path, name: str, fields: str, problems: list[Problem]) -> list[_Row]:
    """The data lines of ``name`` (``#`` comments and blank lines skipped), sorted by time."""
    width = len(fields.split())
    rows: list[_Row] = []
    for number, line in enumerate(_lines(root, name), start=1):
        values = line.split()
        if not values or values[0].startswith("#"):
            continue
        where = f"{name}:line {number}"
        if len(values) != width:
            problems.append(
                Problem(where, f"expected {width} values ({fields}), got {len(values)}")
            )
            continue
        try:
            stamp = float(values[0])
        except ValueError:
            stamp = float("nan")
        if not np.isfinite(stamp):
            problems.append(Problem(where, f"timestamp {values[0]!r} is not a number"))
            continue
        rows.append(_Row(stamp, values[0], number, tuple(values[1:])))
    return sorted(rows, key=lambda r: r.stamp)


def _pose(row: _Row) -> NDArray[np.float64] | str:
    try:
        numbers = [float(v) for v in row.values]
    except ValueError:
        return f"timestamp {row.text}: pose values must be numbers ({_POSE_FIELDS})"
    if not np.all(np.isfinite(numbers)):
        return f"timestamp {row.text}: pose values must be finite"
    tx, ty, tz, qx, qy, qz, qw = numbers
    pose = quaternion_pose([qx, qy, qz, qw, tx, ty, tz])
    return pose if not isinstance(pose, str) else f"timestamp {row.text}: {pose}"


def _camera(root: Path, options: CaptureOptions) -> Camera:
    if not (root / CALIBRATION).is_file():
        camera = options_camera(options)
        if camera is None:
            raise InputError.single(str(root), _NO_INTRINSICS)
        return camera
    warn_if_options_intrinsics(options, "TUM (with calibration.txt)")
    values = " ".join(_lines(root, CALIBRATION)).split()
    try:
        numbers = [float(v) for v in values]
    except ValueError:
        numbers = []
    if len(numbers) not in (4, 8, 9, 12) or not all(math.isfinite(v) for v in numbers):
        raise InputError.single(
            CALIBRATION,
            "expected 4 numbers 'fx fy cx cy', optionally followed by 4, 5 or 8 OpenCV "
            f"distortion coefficients 'k1 k2 p1 p2 [k3 [k4 k5 k6]]', got {' '.join(values)[:80]!r}",
        )
    fx, fy, cx, cy = numbers[:4]
    lens = Lens("opencv", tuple(numbers[4:]), CALIBRATION) if len(numbers) > 4 else None
    return Camera(fx, fy, cx, cy, None, CALIBRATION, lens)


class _Times:
    """Rows sorted by time, searched for the one nearest a timestamp."""

    def __init__(self, rows: list[_Row]) -> None:
        self.rows = rows
        self.stamps = np.array([r.stamp for r in rows], dtype=np.float64)

    def nearest(self, stamp: float) -> tuple[_Row | None, float]:
        """The nearest row and its distance in seconds (None, inf when there are no rows)."""
        if not self.rows:
            return None, float("inf")
        i = int(np.searchsorted(self.stamps, stamp))
        near = [j for j in (i - 1, i) if 0 <= j < len(self.rows)]
        best = min(near, key=lambda j: abs(self.stamps[j] - stamp))
        return self.rows[best], abs(float(self.stamps[best]) - stamp)

    def spans(self, stamp: float, tolerance: float) -> bool:
        """Whether ``stamp`` lies within the rows' time span (widened by ``tolerance``)."""
        if not self.rows:
            return False
        return bool(self.stamps[0] - tolerance <= stamp <= self.stamps[-1] + tolerance)


def _inside(root: Path, value: str, where: str, problems: list[Problem]) -> Path | None:
    path = inside(root, value)
    if path is None:
        problems.append(
            Problem(where, f"path {value!r} must be relative to and inside the capture")
        )
    return path


def _no_match(row: _Row, part: str, source: str, gap: float, tolerance: float) -> Problem:
    nearest = "it is empty" if gap == float("inf") else f"the nearest is {gap * 1000:.1f} ms away"
    return Problem(
        f"{RGB}:line {row.line}",
        f"timestamp {row.text}: no {part} in {source} within {tolerance * 1000:g} ms ({nearest})",
    )


def list_frames(root: Path, options: CaptureOptions) -> Listing:
    """List the frames of a TUM RGB-D folder in time order.

    Args:
        root: the folder holding ``rgb.txt``, ``depth.txt`` and ``groundtruth.txt``.
        options: ``intrinsics`` is used when there is no ``calibration.txt``;
            ``sync_tolerance_ms`` is the largest time difference accepted when associating
            (None = :data:`TOLERANCE`, 20 ms).

    Raises:
        InputError: no intrinsics, or ``groundtruth.txt`` is missing.
    """
    ms = options.sync_tolerance_ms
    tolerance = TOLERANCE if ms is None else ms / 1000.0
    camera = _camera(root, options)
    if not (root / POSES).is_file():
        raise InputError.single(POSES, f"missing: TUM captures need poses ({_POSE_FIELDS})")
    listing = Listing()
    colour = _table(root, RGB, "timestamp filename", listing.problems)
    depth = _Times(_table(root, DEPTH, "timestamp filename", listing.problems))
    poses = _Times(_table(root, POSES, _POSE_FIELDS, listing.problems))
    dropped = [row for row in colour if not poses.spans(row.stamp, tolerance)]
    for row in colour:
        if poses.spans(row.stamp, tolerance):
            _add_frame(root, row, depth, poses, tolerance, camera, listing)
    _report_dropped(dropped, colour, poses, listing)
    return listing


def _add_frame(
    root: Path,
    row: _Row,
    depth: _Times,
    poses: _Times,
    tolerance: float,
    camera: Camera,
    listing: Listing,
) -> None:
    problems = listing.problems
    before = len(problems)
    rgb = _inside(root, row.values[0], f"{RGB}:line {row.line}", problems)
    match, gap = depth.nearest(row.stamp)
    if match is None or gap > tolerance:
        problems.append(_no_match(row, "depth image", DEPTH, gap, tolerance))
        match = None
    where = f"{DEPTH}:line {match.line}" if match is not None else ""
    depth_file = _inside(root, match.values[0], where, problems) if match is not None else None
    pose_row, pose_gap = poses.nearest(row.stamp)
    pose: NDArray[np.float64] | str = "no pose"
    if pose_row is None or pose_gap > tolerance:
        problems.append(_no_match(row, "pose", POSES, pose_gap, tolerance))
    else:
        pose = _pose(pose_row)
        if isinstance(pose, str):
            problems.append(Problem(f"{POSES}:line {pose_row.line}", pose))
    if len(problems) > before or rgb is None or depth_file is None or isinstance(pose, str):
        listing.unlisted.append(row.text)
        return
    assert pose_row is not None
    source = f"{POSES}:line {pose_row.line}"
    spec = FrameSpec(row.text, rgb, depth_file, pose, camera, source, depth_scale=DEPTH_SCALE)
    add_if_present(listing, spec, root)


def _report_dropped(
    dropped: list[_Row], colour: list[_Row], poses: _Times, listing: Listing
) -> None:
    if not dropped:
        return
    if len(dropped) == len(colour) and not listing.problems:
        span = (
            f"the poses span {poses.stamps[0]:.6f} to {poses.stamps[-1]:.6f}"
            if poses.rows
            else "it has no poses"
        )
        listing.problems.append(
            Problem(
                POSES,
                f"no colour frame lies within its time span ({span}; the colour frames span "
                f"{colour[0].text} to {colour[-1].text})",
            )
        )
        return
    logger.warning(
        "TUM: %d of %d colour frames lie outside the time span of %s and are dropped (first: %s)",
        len(dropped),
        len(colour),
        POSES,
        dropped[0].text,
    )
