"""nerfstudio's ``transforms.json`` layout (with depth).

::

    {"fl_x": .., "fl_y": .., "cx": .., "cy": .., "w": .., "h": ..,
     "depth_unit_scale_factor": 0.001,
     "frames": [{"file_path": "images/frame_00001.png",
                 "depth_file_path": "depth/frame_00001.png",
                 "transform_matrix": [[4x4]]}, ...]}

Camera keys may be global or per frame (per frame wins); ``w``/``h`` are optional.
``transform_matrix`` is camera-to-world in OpenGL/nerfstudio camera axes (x right, y up, z back)
and is converted to OpenCV axes by right-multiplying with ``diag(1, -1, -1, 1)``;
``applied_transform`` is already folded into it and is ignored. Depth PNGs are uint16 with
metres = value * ``depth_unit_scale_factor`` (default 0.001, i.e. millimetres). Every frame needs
a ``depth_file_path``. Lens distortion (``camera_model`` ``OPENCV``, the default, with ``k1 k2
k3 p1 p2``, or ``OPENCV_FISHEYE`` with ``k1..k4``; global or per frame) is removed when the frames
are read (:mod:`dcseg.lens`). Frames are named by the stem of ``file_path``.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any, Literal

import numpy as np

from dcseg.config import CaptureOptions
from dcseg.io.captures.common import (
    Camera,
    FrameSpec,
    Listing,
    add_if_present,
    warn_if_options_intrinsics,
)
from dcseg.io.captures.jsonfields import JsonFields, join, load_json
from dcseg.types import Lens

__all__ = ["OPENGL_TO_OPENCV", "TRANSFORMS", "list_frames", "matches"]

logger = logging.getLogger(__name__)

TRANSFORMS = "transforms.json"
OPENGL_TO_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])
"""Right-multiply an OpenGL-axes camera-to-world pose by this to get OpenCV axes."""

_CAMERA_KEYS = ("fl_x", "fl_y", "cx", "cy")
_DISTORTION_KEYS = ("k1", "k2", "k3", "k4", "p1", "p2")
_DEFAULT_UNIT = 0.001


def matches(root: Path) -> bool:
    """Whether ``root`` has a ``transforms.json``."""
    return (root / TRANSFORMS).is_file()


def _holder(
    doc: dict[str, Any], frame: dict[str, Any], key: str, where: str
) -> tuple[dict[str, Any], str, str]:
    """The object holding camera ``key`` (the frame's own value wins), ``key`` and its path."""
    return (frame, key, where) if key in frame else (doc, key, "")


def _camera(
    fields: JsonFields, doc: dict[str, Any], frame: dict[str, Any], where: str
) -> Camera | None:
    values: list[float | None] = []
    for key in _CAMERA_KEYS:
        holder, _, at = _holder(doc, frame, key, where)
        if key not in holder:
            fields.add(join(where, key), "missing (neither in the frame nor at the top level)")
        values.append(fields.number(holder, key, at, required=False))
    width, height = (fields.integer(*_holder(doc, frame, k, where), required=False) for k in "wh")
    lens = _lens(fields, doc, frame, where)
    if None in values or lens is False:
        return None
    fx, fy, cx, cy = (float(v) for v in values if v is not None)
    stated = (width, height) if width is not None and height is not None else None
    return Camera(fx, fy, cx, cy, stated, f"{TRANSFORMS}:{where}", lens or None)


def _unit(fields: JsonFields, doc: dict[str, Any]) -> float:
    factor = fields.number(doc, "depth_unit_scale_factor", "", required=False)
    if factor is not None and factor <= 0:
        fields.add("depth_unit_scale_factor", f"must be > 0, got {factor}")
        return _DEFAULT_UNIT
    return factor or _DEFAULT_UNIT


def _lens(
    fields: JsonFields, doc: dict[str, Any], frame: dict[str, Any], where: str
) -> Lens | None | Literal[False]:
    """The frame's lens in OpenCV's order (None = no distortion, False = a problem, added to
    ``fields``): nerfstudio's ``OPENCV`` is radial ``k1 k2 k3`` (its ``k4``, an ``r^8`` term
    OpenCV lacks, must be 0) and tangential ``p1 p2``; ``OPENCV_FISHEYE`` is ``k1..k4``."""
    values = {}
    for key in _DISTORTION_KEYS:
        holder, _, at = _holder(doc, frame, key, where)
        values[key] = fields.number(holder, key, at, required=False) or 0.0
    holder, key, at = _holder(doc, frame, "camera_model", where)
    model = fields.string(holder, key, at, required=False) or "OPENCV"
    k1, k2, k3, k4, p1, p2 = (values[key] for key in _DISTORTION_KEYS)
    source = f"{TRANSFORMS}:{join(at, 'camera_model')} {model}"
    if model == "OPENCV_FISHEYE" and not (p1 or p2):
        return Lens("fisheye", (k1, k2, k3, k4), source) if any(values.values()) else None
    if model == "OPENCV" and not k4:
        return Lens("opencv", (k1, k2, p1, p2, k3), source) if any(values.values()) else None
    reason = {
        "OPENCV": "k4 (nerfstudio's r^8 term) has no OpenCV equivalent; dcseg reads k1 k2 k3 p1 p2",
        "OPENCV_FISHEYE": "a fisheye camera has no p1 / p2",
    }.get(model, f"{model} is not supported (OPENCV or OPENCV_FISHEYE)")
    fields.add(join(at, "camera_model"), reason)
    return False


def _frame(
    fields: JsonFields, root: Path, doc: dict[str, Any], item: Any, where: str, unit: float
) -> FrameSpec | None:
    frame = fields.mapping(item, where)
    if frame is None:
        return None
    rgb_value = fields.string(frame, "file_path", where)
    rgb = fields.relative_file(root, rgb_value, join(where, "file_path"))
    depth_value = fields.string(frame, "depth_file_path", where, required=False)
    if depth_value is None and "depth_file_path" not in frame:
        fields.add(join(where, "depth_file_path"), "missing (dcseg needs depth for every frame)")
    depth = fields.relative_file(root, depth_value, join(where, "depth_file_path"))
    gl = fields.matrix4(frame, "transform_matrix", where)
    camera = _camera(fields, doc, frame, where)
    if rgb is None or depth is None or gl is None or camera is None:
        return None
    pose = f"{TRANSFORMS}:{join(where, 'transform_matrix')}"
    name = Path(rgb_value or "").stem
    return FrameSpec(name, rgb, depth, gl @ OPENGL_TO_OPENCV, camera, pose, depth_scale=1 / unit)


def list_frames(root: Path, options: CaptureOptions) -> Listing:
    """List the frames of a nerfstudio folder.

    Raises:
        InputError: ``transforms.json`` is not valid JSON or lacks required fields (all of them).
    """
    warn_if_options_intrinsics(options, "nerfstudio")
    fields = JsonFields(TRANSFORMS)
    doc = fields.mapping(load_json(root / TRANSFORMS, TRANSFORMS), "")
    if doc is None:
        fields.raise_if_any()
        return Listing()
    unit = _unit(fields, doc)
    value = fields.get(doc, "frames", "")
    items = fields.array(value, "frames") if value is not None else None
    specs = [
        _frame(fields, root, doc, item, join("frames", i), unit)
        for i, item in enumerate(items or [])
    ]
    fields.raise_if_any()
    listing = Listing()
    for spec in specs:
        if spec is not None:
            add_if_present(listing, spec, root)
    return listing
