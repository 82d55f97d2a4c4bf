"""Record3D's ``.r3d`` export (a zip archive; read as a file or as the extracted folder).

::

    metadata                 JSON: {"K": [9], "w": W, "h": H, "dw": DW, "dh": DH,
                                    "poses": [[qx, qy, qz, qw, tx, ty, tz], ...], ...}
    rgbd/<i>.jpg             colour, W x H
    rgbd/<i>.depth           LZFSE-compressed float32 metres, DW x DH, row-major (0/NaN = none)
    rgbd/<i>.conf            LZFSE-compressed uint8 ARKit confidence, DW x DH (0 low .. 2 high)

``K`` is the colour camera matrix stored column-major (``fx = K[0]``, ``fy = K[4]``,
``cx = K[6]``, ``cy = K[7]``) for ``w x h`` images. ``poses[i]`` is frame ``i``'s ARKit
camera-to-world pose (scalar-last quaternion, translation in metres), converted to OpenCV camera
axes as described in :mod:`dcseg.io.captures.arkit`; there must be one pose per colour image.
Depth has its own (LiDAR) resolution and is resampled onto the colour grid with nearest
neighbour. Each compressed buffer is decoded into exactly the size ``dw * dh`` implies
(:mod:`dcseg.io.lzfse_buffers`). Confidence is read only with
``CaptureOptions.min_confidence`` > 0. Other metadata keys (``fps``, ``initPose``,
``frameTimestamps``, ``perFrameIntrinsicCoeffs``) are not used. Frames are named ``<i>``.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dcseg.config import CaptureOptions
from dcseg.io.captures.arkit import opencv_pose, quaternion_pose
from dcseg.io.captures.common import (
    Camera,
    FrameSpec,
    Listing,
    add_if_present,
    warn_if_options_intrinsics,
)
from dcseg.io.captures.jsonfields import JsonFields, join, load_json

__all__ = ["METADATA", "R3D_SUFFIX", "RGBD", "list_frames", "matches"]

METADATA = "metadata"
RGBD = "rgbd"
R3D_SUFFIX = ".r3d"
"""A Record3D export file: a zip archive of this layout."""

_COLOUR = re.compile(r"(\d+)\.(jpg|jpeg|png)", re.IGNORECASE)
_POSE_LENGTH = 7


def matches(root: Path) -> bool:
    """Whether ``root`` has Record3D's ``metadata`` file and ``rgbd/`` folder."""
    return (root / METADATA).is_file() and (root / RGBD).is_dir()


def _intrinsics(fields: JsonFields, doc: dict[str, Any]) -> Camera | None:
    value = fields.get(doc, "K", "")
    width, height = fields.integer(doc, "w", ""), fields.integer(doc, "h", "")
    if value is None:
        return None
    k = _numbers(fields, value, "K", 9, "a 3x3 camera matrix as 9 numbers, column-major")
    if k is None or width is None or height is None:
        return None
    return Camera(k[0], k[4], k[6], k[7], (width, height), f"{METADATA}:K")


def _numbers(
    fields: JsonFields, value: Any, where: str, count: int, what: str
) -> list[float] | None:
    ok = isinstance(value, list) and len(value) == count
    numbers = (
        [v for v in value if isinstance(v, int | float) and not isinstance(v, bool)] if ok else []
    )
    if not ok or len(numbers) != count or not all(np.isfinite(numbers)):
        fields.add(where, f"must be {what}")
        return None
    return [float(v) for v in numbers]


def _pose(fields: JsonFields, value: Any, where: str) -> NDArray[np.float64] | None:
    numbers = _numbers(fields, value, where, _POSE_LENGTH, "7 numbers [qx, qy, qz, qw, tx, ty, tz]")
    if numbers is None:
        return None
    pose = quaternion_pose(numbers)
    if isinstance(pose, str):
        fields.add(where, pose)
        return None
    return opencv_pose(pose)


def _colour_files(root: Path) -> list[tuple[int, Path]]:
    found = [(m, p) for p in (root / RGBD).iterdir() if (m := _COLOUR.fullmatch(p.name))]
    return sorted((int(m.group(1)), p) for m, p in found)


def _header(
    fields: JsonFields, doc: dict[str, Any]
) -> tuple[Camera | None, tuple[int, int] | None]:
    camera = _intrinsics(fields, doc)
    dw, dh = fields.integer(doc, "dw", ""), fields.integer(doc, "dh", "")
    return camera, (dw, dh) if dw is not None and dh is not None else None


def _poses(
    fields: JsonFields, doc: dict[str, Any], frames: int
) -> list[NDArray[np.float64] | None]:
    value = fields.get(doc, "poses", "")
    items = fields.array(value, "poses") if value is not None else None
    if items is None:
        return []
    if len(items) != frames:
        fields.add("poses", f"has {len(items)} poses but {RGBD}/ holds {frames} colour images")
    return [_pose(fields, item, join("poses", i)) for i, item in enumerate(items)]


def list_frames(root: Path, options: CaptureOptions) -> Listing:
    """List the frames of a Record3D export folder.

    Raises:
        InputError: ``metadata`` is not valid JSON, lacks a field, has a malformed one, or
            holds another number of poses than there are colour images (all problems at once).
    """
    warn_if_options_intrinsics(options, "Record3D")
    fields = JsonFields(METADATA)
    doc = fields.mapping(load_json(root / METADATA, METADATA), "")
    if doc is None:
        fields.raise_if_any()
        return Listing()
    colour = _colour_files(root)
    camera, raw_size = _header(fields, doc)
    poses = _poses(fields, doc, len(colour))
    for index, rgb in colour:
        if index >= len(poses) and "poses" in doc:
            fields.add("poses", f"has no pose for {RGBD}/{rgb.name} (needs entry {index})")
    fields.raise_if_any()
    assert camera is not None and raw_size is not None
    listing = Listing(resample_depth=True)
    for index, rgb in colour:
        pose = poses[index]
        assert pose is not None
        spec = FrameSpec(
            str(index),
            rgb,
            rgb.with_suffix(".depth"),
            pose,
            camera,
            f"{METADATA}:{join('poses', index)}",
            raw_size=raw_size,
            confidence=rgb.with_suffix(".conf"),
        )
        add_if_present(listing, spec, root)
    return listing
