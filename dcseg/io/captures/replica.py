"""NICE-SLAM's Replica layout.

::

    results/frameNNNNNN.jpg|png    colour
    results/depthNNNNNN.png        uint16 depth, value / 6553.5 = metres, 0 = invalid
    traj.txt                       row i = frame i: 16 floats, row-major 4x4 camera-to-world
    cam_params.json                optional: {"camera": {"w", "h", "fx", "fy", "cx", "cy", "scale"}}

``traj.txt`` may have more rows than there are frames (a subset of a longer sequence); frame
``frameNNNNNN`` uses row ``NNNNNN``. Intrinsics come from ``cam_params.json`` (whose ``scale``
replaces 6553.5 as the depth scale), else from ``CaptureOptions.intrinsics``. Frames are named
by the colour stem (``frame000000``).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from dcseg.config import CaptureOptions
from dcseg.errors import InputError, Problem
from dcseg.io.captures.common import (
    Camera,
    FrameSpec,
    Listing,
    missing,
    options_camera,
    warn_if_options_intrinsics,
)
from dcseg.io.captures.jsonfields import JsonFields, load_json

__all__ = ["DEPTH_SCALE", "list_frames", "matches"]

DEPTH_SCALE = 6553.5
"""NICE-SLAM's Replica depth scale: stored value / 6553.5 = metres."""

_COLOUR = re.compile(r"frame(\d+)\.(jpg|jpeg|png)", re.IGNORECASE)
_PARAMS = "cam_params.json"
_TRAJ = "traj.txt"
_NO_INTRINSICS = (
    "no intrinsics: Replica captures need cam_params.json "
    '({"camera": {"w": W, "h": H, "fx": .., "fy": .., "cx": .., "cy": .., "scale": 6553.5}}) '
    "or CaptureOptions(intrinsics=(fx, fy, cx, cy)) at the colour resolution"
)


def matches(root: Path) -> bool:
    """Whether ``root`` has NICE-SLAM's ``results/`` folder and ``traj.txt``."""
    return (root / "results").is_dir() and (root / _TRAJ).is_file()


def _params(root: Path) -> tuple[Camera, float]:
    fields = JsonFields(_PARAMS)
    doc = fields.mapping(load_json(root / _PARAMS, _PARAMS), "")
    cam = fields.mapping(fields.get(doc, "camera", ""), "camera") if doc is not None else None
    if cam is None:
        raise InputError(fields.problems)
    fx, fy, cx, cy = (fields.number(cam, key, "camera") for key in ("fx", "fy", "cx", "cy"))
    width, height = fields.integer(cam, "w", "camera"), fields.integer(cam, "h", "camera")
    scale = fields.number(cam, "scale", "camera", required=False)
    fields.raise_if_any()
    assert fx is not None and fy is not None and cx is not None and cy is not None
    size = (width, height) if width is not None and height is not None else None
    return Camera(fx, fy, cx, cy, size, f"{_PARAMS}:camera"), scale or DEPTH_SCALE


def _camera(root: Path, options: CaptureOptions) -> tuple[Camera, float]:
    if (root / _PARAMS).is_file():
        warn_if_options_intrinsics(options, "Replica (with cam_params.json)")
        return _params(root)
    camera = options_camera(options)
    if camera is None:
        raise InputError.single(str(root), _NO_INTRINSICS)
    return camera, DEPTH_SCALE


def _trajectory(root: Path) -> list[str]:
    try:
        return (root / _TRAJ).read_text(encoding="utf-8", errors="replace").splitlines()
    except OSError as exc:
        raise InputError.single(_TRAJ, f"cannot read file ({exc.strerror})") from None


def _pose(rows: list[str], index: int) -> NDArray[np.float64]:
    if index >= len(rows):
        raise InputError.single(
            _TRAJ, f"has {len(rows)} poses but frame {index} needs line {index + 1}"
        )
    try:
        values = [float(v) for v in rows[index].split()]
    except ValueError:
        values = []
    if len(values) != 16:
        raise InputError.single(
            f"{_TRAJ}:line {index + 1}", "expected 16 numbers (a row-major 4x4 pose)"
        )
    return np.array(values, dtype=np.float64).reshape(4, 4)


def list_frames(root: Path, options: CaptureOptions) -> Listing:
    """List the frames of a NICE-SLAM Replica folder.

    Raises:
        InputError: no intrinsics are available, or ``cam_params.json`` is malformed.
    """
    camera, scale = _camera(root, options)
    rows = _trajectory(root)
    colour = [(m, p) for p in (root / "results").iterdir() if (m := _COLOUR.fullmatch(p.name))]
    listing = Listing()
    for match, rgb in sorted(colour, key=lambda mp: (int(mp[0].group(1)), mp[1].name)):
        spec = _spec(root, rgb, match.group(1), rows, camera, scale, listing.problems)
        if spec is not None:
            listing.specs.append(spec)
        else:
            listing.unlisted.append(rgb.stem)
    return listing


def _spec(
    root: Path,
    rgb: Path,
    digits: str,
    rows: list[str],
    camera: Camera,
    scale: float,
    problems: list[Problem],
) -> FrameSpec | None:
    depth = root / "results" / f"depth{digits}.png"
    ok = depth.is_file()
    if not ok:
        problems.append(missing(depth, root, "depth", rgb))
    try:
        c2w = _pose(rows, int(digits))
    except InputError as exc:
        problems.extend(exc.problems)
        return None
    if not ok:
        return None
    source = f"{_TRAJ}:line {int(digits) + 1}"
    return FrameSpec(rgb.stem, rgb, depth, c2w, camera, source, depth_scale=scale)
