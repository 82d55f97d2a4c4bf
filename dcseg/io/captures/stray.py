"""Stray Scanner recordings (Stray Robots' iOS app), as the app writes them.

::

    rgb.mp4                  colour video (HEVC on the phone), one frame per odometry row
    rgb/<NNNNNN>.jpg|png     or colour frames as images (some exports); used when present
    depth/<NNNNNN>.png       uint16 millimetres, 256x192, 0 = none (older versions: .npy)
    confidence/<NNNNNN>.png  ARKit confidence 0, 1, 2 at the depth resolution
    odometry.csv             "timestamp, frame, x, y, z, qx, qy, qz, qw" per frame
    camera_matrix.csv        3x3 colour camera matrix, rows comma-separated
    imu.csv                  not used

The format is the app's ``docs/format.md``; the conventions are those of its encoder
(``OdometryEncoder.swift``) and reference reader (StrayVisualizer's ``stray_visualize.py``):

* **Poses**: the app writes ARKit's camera transform with its rotation turned by ``q_AC``, a
  half-turn about the camera's x axis (``q = q_WA * q_AC``), so ``[R(qx, qy, qz, qw) | x y z]``
  is already camera-to-world in OpenCV camera axes (x right, y down, z forward), the matrix
  StrayVisualizer hands to Open3D. It is taken as it is; the world frame is ARKit's
  (gravity-aligned, y up, metres, origin where the recording started). Files without a header
  (older versions) hold ``x, y, z, qx, qy, qz, qw`` (7 values) or all 9; frames are then
  numbered by row.
* **Intrinsics**: ``camera_matrix.csv`` is ARKit's camera matrix of the captured image, the
  video's resolution (1920x1440). StrayVisualizer scales it to the depth maps' 256x192 and works
  there; dcseg keeps the colour resolution and puts depth on the colour grid (nearest
  neighbour; the aspect ratios agree), so the matrix is used as written. Colour images of
  another size (an ``rgb/`` export) scale it with the pixel-centre convention of
  ``docs/conventions.md`` (same aspect ratio required).
* **Confidence**: StrayVisualizer keeps depth with confidence >= 1 and its Open3D converter
  >= 2; here ``CaptureOptions.min_confidence`` decides (0 = keep all, confidence not read).

Frame ``i`` of the video belongs to the ``i``-th odometry row (the app encodes one video frame
per saved frame, in order). Rows beyond the video's last frame are dropped with a warning, as
StrayVisualizer's ``zip`` of poses and frames drops them. Frames are named by their number
(``000012``), which masks are matched to.
"""

from __future__ import annotations

import logging
import re
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
    rel,
    warn_if_options_intrinsics,
)
from dcseg.io.images import image_size

__all__ = ["CAMERA_MATRIX", "ODOMETRY", "VIDEO", "list_frames", "matches"]

logger = logging.getLogger(__name__)

ODOMETRY = "odometry.csv"
CAMERA_MATRIX = "camera_matrix.csv"
VIDEO = "rgb.mp4"
_COLUMNS = ("timestamp", "frame", "x", "y", "z", "qx", "qy", "qz", "qw")
_POSE_COLUMNS = ("x", "y", "z", "qx", "qy", "qz", "qw")
_COLOUR = re.compile(r"(\d+)\.(jpg|jpeg|png)", re.IGNORECASE)


def matches(root: Path) -> bool:
    """Whether ``root`` holds ``odometry.csv``, ``camera_matrix.csv``, ``depth/`` and colour
    (``rgb.mp4`` or ``rgb/``)."""
    return (
        (root / ODOMETRY).is_file()
        and (root / CAMERA_MATRIX).is_file()
        and (root / "depth").is_dir()
        and ((root / VIDEO).is_file() or (root / "rgb").is_dir())
    )


@dataclass(frozen=True)
class _Row:
    """One odometry row: its frame number, pose (OpenCV camera-to-world) and line."""

    frame: int
    c2w: NDArray[np.float64]
    line: int


def list_frames(root: Path, options: CaptureOptions) -> Listing:
    """List one frame per odometry row, colour from ``rgb/`` images or the video.

    Raises:
        InputError: a malformed ``odometry.csv`` or ``camera_matrix.csv`` (naming the line),
            an unreadable video, or no odometry row.
    """
    warn_if_options_intrinsics(options, "Stray Scanner")
    rows = _odometry(root / ODOMETRY, rel(root / ODOMETRY, root))
    camera = _camera_matrix(root / CAMERA_MATRIX, root)
    listing = Listing(resample_depth=True)
    images = _colour_images(root / "rgb")
    if images:
        camera = _for_images(camera, images, root)
        for row in rows:
            rgb = images.get(row.frame, root / "rgb" / f"{row.frame:06d}.jpg")
            add_if_present(listing, _spec(root, row, rgb, camera, None), root)
        return listing
    from dcseg.io.video import video_frames, video_size

    if not (root / VIDEO).is_file():
        reason = f"no colour: no {VIDEO} and no NNNNNN.jpg / .png images in rgb/"
        raise InputError.single(rel(root / "rgb", root), reason)
    size = video_size(root / VIDEO)
    if size is None:
        raise InputError.single(VIDEO, "cannot open video (corrupt, or a codec FFmpeg lacks)")
    camera = _stated(camera, size)
    count = video_frames(root / VIDEO, root)
    _report_beyond(rows, count, listing)
    for index, row in enumerate(rows[:count]):
        spec = _spec(root, row, root / VIDEO, camera, index)
        assert spec.depth is not None  # Stray Scanner always has depth
        if spec.depth.is_file():
            listing.specs.append(spec)
        else:
            reason = (
                f"missing (frame {index} of {VIDEO}, odometry.csv:line {row.line}, has no depth)"
            )
            listing.unlist(spec.name, [Problem(rel(spec.depth, root), reason)])
    return listing


def _spec(root: Path, row: _Row, rgb: Path, camera: Camera, index: int | None) -> FrameSpec:
    name = f"{row.frame:06d}"
    depth = root / "depth" / f"{name}.png"
    if not depth.is_file() and (root / "depth" / f"{name}.npy").is_file():
        depth = root / "depth" / f"{name}.npy"  # older versions
    confidence = root / "confidence" / f"{name}.png"
    source = f"{ODOMETRY}:line {row.line}"
    return FrameSpec(
        name, rgb, depth, row.c2w, camera, source, confidence=confidence, rgb_frame=index
    )


def _report_beyond(rows: list[_Row], count: int, listing: Listing) -> None:
    if count >= len(rows):
        return
    if count == 0:
        listing.problems.append(Problem(VIDEO, "the video holds no frame"))
        return
    logger.warning(
        "Stray Scanner: %s has %d frames for %d odometry rows; frames from %06d on are dropped",
        VIDEO,
        count,
        len(rows),
        rows[count].frame,
    )


# --------------------------------------------------------------------------- odometry.csv


def _odometry(path: Path, shown: str) -> list[_Row]:
    """Every row of ``odometry.csv``, in file order; InputError names a malformed line."""
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        raise InputError.single(shown, f"cannot read file ({exc.strerror})") from None
    lines = [(n, line) for n, line in enumerate(text.splitlines(), start=1) if line.strip()]
    if not lines:
        raise InputError.single(shown, "no odometry rows")
    columns, body = _header(lines, shown)
    rows: list[_Row] = []
    problems: list[Problem] = []
    for number, line in body:
        try:
            rows.append(_row(line, number, columns, len(rows)))
        except ValueError as exc:
            problems.append(Problem(f"{shown}:line {number}", str(exc)))
    problems += _duplicates(rows, shown)
    if problems:
        raise InputError(problems)
    if not rows:
        raise InputError.single(shown, "no odometry rows after the header")
    return rows


def _header(
    lines: list[tuple[int, str]], shown: str
) -> tuple[tuple[str, ...] | None, list[tuple[int, str]]]:
    """The named columns (None = headerless, by count) and the data lines."""
    first = [v.strip().lower() for v in lines[0][1].split(",")]
    if all(_is_number(v) for v in first):
        return None, lines
    lacking = [c for c in _POSE_COLUMNS if c not in first]
    if lacking:
        reason = f"header {', '.join(first)!r} lacks column(s) {', '.join(lacking)}"
        raise InputError.single(f"{shown}:line {lines[0][0]}", reason)
    return tuple(first), lines[1:]


def _row(line: str, number: int, columns: tuple[str, ...] | None, position: int) -> _Row:
    values = [v.strip() for v in line.split(",")]
    names = columns or _headerless(len(values))
    if len(values) != len(names):
        raise ValueError(f"expected {len(names)} values ({', '.join(names)}), got {len(values)}")
    fields = dict(zip(names, values, strict=True))
    try:
        pose = [float(fields[c]) for c in _POSE_COLUMNS]
    except ValueError:
        raise ValueError(f"pose values must be numbers, got {line.strip()!r}") from None
    if not np.all(np.isfinite(pose)):
        raise ValueError(f"pose values must be finite, got {line.strip()!r}")
    frame = _frame_number(fields.get("frame"), position)
    c2w = quaternion_pose([*pose[3:], *pose[:3]])
    if isinstance(c2w, str):
        raise ValueError(c2w)
    return _Row(frame, c2w, number)


def _headerless(count: int) -> tuple[str, ...]:
    if count == len(_COLUMNS):
        return _COLUMNS
    if count == len(_POSE_COLUMNS):
        return _POSE_COLUMNS
    return _COLUMNS  # the error names the current layout's columns


def _frame_number(value: str | None, position: int) -> int:
    if value is None:
        return position
    if not value.isdigit():
        raise ValueError(f"frame must be a non-negative integer like 000012, got {value!r}")
    return int(value)


def _duplicates(rows: list[_Row], shown: str) -> list[Problem]:
    seen: dict[int, int] = {}
    problems = []
    for row in rows:
        if row.frame in seen:
            reason = f"frame {row.frame:06d} appears again (first on line {seen[row.frame]})"
            problems.append(Problem(f"{shown}:line {row.line}", reason))
        seen.setdefault(row.frame, row.line)
    return problems


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


# --------------------------------------------------------------------------- intrinsics


def _camera_matrix(path: Path, root: Path) -> Camera:
    """``camera_matrix.csv`` as a camera (its size not yet known)."""
    shown = rel(path, root)
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        raise InputError.single(shown, f"cannot read file ({exc.strerror})") from None
    try:
        rows = [[float(v) for v in line.split(",")] for line in text.splitlines() if line.strip()]
        matrix = np.array(rows, dtype=np.float64)
    except ValueError:
        raise InputError.single(shown, "expected a 3x3 matrix of comma-separated numbers") from None
    if matrix.shape != (3, 3) or not np.all(np.isfinite(matrix)):
        raise InputError.single(shown, f"expected a 3x3 matrix of finite numbers, got {rows}")
    fx, fy, cx, cy = matrix[0, 0], matrix[1, 1], matrix[0, 2], matrix[1, 2]
    if fx <= 0 or fy <= 0:
        raise InputError.single(shown, f"fx and fy must be positive, got {fx:g} and {fy:g}")
    if not np.allclose(matrix[2], (0.0, 0.0, 1.0)) or matrix[1, 0] != 0:
        raise InputError.single(shown, f"expected a pinhole matrix with last row 0, 0, 1: {rows}")
    return Camera(float(fx), float(fy), float(cx), float(cy), None, shown)


def _stated(camera: Camera, size: tuple[int, int]) -> Camera:
    return Camera(camera.fx, camera.fy, camera.cx, camera.cy, size, camera.source)


def _colour_images(folder: Path) -> dict[int, Path]:
    if not folder.is_dir():
        return {}
    found = ((_COLOUR.fullmatch(p.name), p) for p in folder.iterdir() if p.is_file())
    return {int(m.group(1)): p for m, p in found if m}


def _for_images(camera: Camera, images: dict[int, Path], root: Path) -> Camera:
    """The camera for ``rgb/`` images: stated for the video's size when the video is there
    (scaled to the images' size), else for the images' own size."""
    from dcseg.io.video import video_size

    first = images[min(images)]
    size = image_size(first)
    video = video_size(root / VIDEO) if (root / VIDEO).is_file() else None
    if size is None or video is None or video == size:
        return _stated(camera, size) if size is not None else camera
    sx, sy = size[0] / video[0], size[1] / video[1]
    if abs(sx - sy) > 0.01 * max(sx, sy):
        reason = (
            f"{size[0]}x{size[1]} images have another aspect ratio than the video's "
            f"{video[0]}x{video[1]}, which {CAMERA_MATRIX} is stated for"
        )
        raise InputError.single(rel(first, root), reason)
    return Camera(
        camera.fx * sx,
        camera.fy * sy,
        (camera.cx + 0.5) * sx - 0.5,
        (camera.cy + 0.5) * sy - 0.5,
        size,
        f"{camera.source} (scaled from {video[0]}x{video[1]})",
    )
