"""Redwood / Open3D reconstruction system layout: colour and depth folders and a ``.log``
camera trajectory.

::

    image/|rgb/|color/*.jpg|png   colour, paired with depth by sorted order (as Open3D does)
    depth/*.png                   uint16 millimetres (Open3D's default depth_scale 1000), 0 = none
    <name>.log                    the trajectory (``trajectory.log``, ``odometry.log``, ...)
    camera_intrinsic.json         optional: Open3D's PinholeCameraIntrinsic JSON (+ Stray's
                                  optional ``depth_scale``: stored value / scale = metres)

The ``.log`` format (http://redwood-data.org/indoor/fileformat.html): every five lines are one
item, a metadata line of three integers and four rows of a 4x4 matrix that maps a point from the
camera's coordinates to the world's (camera-to-world). The third metadata number is the frame
number, counted from 1, of the image pair the pose belongs to (Open3D writes ``i i i+1``). The
camera axes are Open3D's, which are OpenCV's (x right, y down, z forward): poses are used as
they are. Frames are the trajectory's items, named by the colour file stem; image pairs with no
item are not read.

The trajectory is ``scene/trajectory.log`` or the ``.log`` file in the capture folder
(``trajectory.log`` when there are several). Intrinsics come from ``camera_intrinsic.json``
(``width``, ``height`` and ``intrinsic_matrix``, the 3x3 matrix stored column-major) or
``CaptureOptions.intrinsics``. Depth may have a lower resolution than colour (same aspect
ratio, as in Stray's dataset format, which this layout also reads once ``stray studio
integrate`` wrote ``scene/trajectory.log``): it is resampled onto the colour grid (nearest).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from dcseg.config import CaptureOptions
from dcseg.errors import InputError, Problem
from dcseg.io.captures.common import (
    Camera,
    FrameSpec,
    Listing,
    add_if_present,
    options_camera,
    rel,
    warn_if_options_intrinsics,
)
from dcseg.io.captures.jsonfields import JsonFields, load_json

__all__ = ["COLOUR_FOLDERS", "DEPTH_SCALE", "list_frames", "matches", "trajectory_file"]

COLOUR_FOLDERS = ("image", "rgb", "color")
"""Colour folder names, in the order Open3D's reconstruction system looks for them."""

DEPTH_SCALE = 1000.0
"""Open3D's default depth scale: a stored value / 1000 = metres."""

_INTRINSICS = "camera_intrinsic.json"
_COLOUR_SUFFIXES = {".jpg", ".jpeg", ".png"}
_NO_INTRINSICS = (
    "no intrinsics: add camera_intrinsic.json (Open3D's PinholeCameraIntrinsic JSON) or pass "
    "CaptureOptions(intrinsics=(fx, fy, cx, cy)) (--intrinsics); Redwood's PrimeSense captures "
    "commonly use 525,525,319.5,239.5 for 640x480"
)


def _colour_folder(root: Path) -> Path | None:
    return next((root / n for n in COLOUR_FOLDERS if (root / n).is_dir()), None)


def trajectory_file(root: Path) -> Path | None:
    """``scene/trajectory.log``, else the capture folder's one ``.log`` (or ``trajectory.log``)."""
    scene = root / "scene" / "trajectory.log"
    if scene.is_file():
        return scene
    logs = sorted(p for p in root.glob("*.log") if p.is_file())
    if len(logs) > 1:
        named = [p for p in logs if p.name == "trajectory.log"]
        return named[0] if named else logs[0]
    return logs[0] if logs else None


def matches(root: Path) -> bool:
    """Whether ``root`` has a colour folder, ``depth/`` and a ``.log`` trajectory."""
    has_folders = _colour_folder(root) is not None and (root / "depth").is_dir()
    return has_folders and trajectory_file(root) is not None


def _check_single_log(root: Path, chosen: Path) -> None:
    logs = sorted(p.name for p in root.glob("*.log") if p.is_file())
    if len(logs) > 1 and chosen.name != "trajectory.log" and chosen.parent == root:
        raise InputError.single(
            ".",
            f"several .log trajectories ({', '.join(logs)}): keep one, or name it trajectory.log",
        )


def _camera(root: Path, options: CaptureOptions) -> tuple[Camera, float]:
    """The intrinsics and the depth scale (stored value / scale = metres)."""
    path = root / _INTRINSICS
    if not path.is_file():
        camera = options_camera(options)
        if camera is None:
            raise InputError.single(".", _NO_INTRINSICS)
        return camera, DEPTH_SCALE
    warn_if_options_intrinsics(options, "Redwood/Open3D (with camera_intrinsic.json)")
    fields = JsonFields(_INTRINSICS)
    doc = fields.mapping(load_json(path, _INTRINSICS), "")
    if doc is None:
        raise InputError(fields.problems)
    width, height = fields.integer(doc, "width", ""), fields.integer(doc, "height", "")
    matrix = fields.array(fields.get(doc, "intrinsic_matrix", ""), "intrinsic_matrix")
    scale = fields.number(doc, "depth_scale", "", required=False)
    if scale is not None and scale <= 0:
        fields.add("depth_scale", f"must be > 0, got {scale:g}")
    fields.raise_if_any()
    assert matrix is not None and width is not None and height is not None
    if len(matrix) != 9 or not all(_finite(v) for v in matrix):
        raise InputError.single(
            _INTRINSICS, "intrinsic_matrix: expected 9 finite numbers (3x3, column-major)"
        )
    fx, fy, cx, cy = (float(matrix[i]) for i in (0, 4, 6, 7))
    return Camera(fx, fy, cx, cy, (width, height), _INTRINSICS), scale or DEPTH_SCALE


def _finite(value: object) -> bool:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return False
    return math.isfinite(value)


def _read_log(path: Path, shown: str) -> list[tuple[int, int, NDArray[np.float64]]]:
    """``(frame number, metadata line, c2w)`` per item of a ``.log`` trajectory."""
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        raise InputError.single(shown, f"cannot read file ({exc.strerror})") from None
    lines = [(n, line.split()) for n, line in enumerate(text.splitlines(), 1) if line.strip()]
    items = []
    for start in range(0, len(lines), 5):
        block = lines[start : start + 5]
        number, meta = block[0]
        if len(block) < 5:
            raise InputError.single(
                f"{shown}:line {number}",
                f"truncated item: a metadata line and 4 matrix rows expected, got {len(block)} "
                "lines",
            )
        items.append((_frame_number(meta, f"{shown}:line {number}"), number, _matrix(block, shown)))
    return items


def _frame_number(meta: list[str], where: str) -> int:
    try:
        values = [int(v) for v in meta]
    except ValueError:
        values = []
    if len(values) != 3:
        raise InputError.single(
            where, f"expected 3 integers of metadata (the third is the frame number), got {meta}"
        )
    if values[2] < 1:
        raise InputError.single(where, f"frame number {values[2]} must be >= 1 (counted from 1)")
    return values[2]


def _matrix(block: list[tuple[int, list[str]]], shown: str) -> NDArray[np.float64]:
    rows = []
    for number, values in block[1:]:
        where = f"{shown}:line {number}"
        try:
            row = [float(v) for v in values]
        except ValueError:
            raise InputError.single(where, f"matrix row must be numbers, got {values}") from None
        if len(row) != 4:
            raise InputError.single(where, f"expected a matrix row of 4 numbers, got {len(row)}")
        rows.append(row)
    return np.array(rows, dtype=np.float64)


def _files(folder: Path, suffixes: set[str]) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in suffixes)


def list_frames(root: Path, options: CaptureOptions) -> Listing:
    """List the frames of the trajectory, pairing colour and depth files by sorted order.

    Raises:
        InputError: no intrinsics; the trajectory is malformed (naming its line); colour and
            depth counts differ; several ``.log`` files and none named ``trajectory.log``.
    """
    log = trajectory_file(root)
    colour_folder = _colour_folder(root)
    assert log is not None and colour_folder is not None
    _check_single_log(root, log)
    camera, scale = _camera(root, options)
    colour = _files(colour_folder, _COLOUR_SUFFIXES)
    depth = _files(root / "depth", {".png"})
    if len(colour) != len(depth):
        raise InputError.single(
            "depth/",
            f"{len(depth)} depth images but {len(colour)} colour images in "
            f"{colour_folder.name}/: they are paired by sorted order, so the counts must agree",
        )
    shown = rel(log, root)
    listing = Listing(resample_depth=True)
    for frame, number, c2w in _read_log(log, shown):
        where = f"{shown}:line {number}"
        if frame > len(colour):
            listing.problems.append(
                Problem(where, f"frame number {frame} but there are {len(colour)} image pairs")
            )
            continue
        rgb = colour[frame - 1]
        spec = FrameSpec(rgb.stem, rgb, depth[frame - 1], c2w, camera, where, depth_scale=scale)
        add_if_present(listing, spec, root)
    return listing
