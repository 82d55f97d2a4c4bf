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

Record3D's "EXR + JPG" export (the ``EXR_RGBD/`` folder) holds the same metadata as
``metadata.json`` (``dw``/``dh`` not needed), with::

    rgb/<i>.jpg              colour, W x H
    depth/<i>.exr            float32 (or half) metres in channel R, the LiDAR resolution

It has no confidence maps, so ``min_confidence`` does not apply to it.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dcseg.config import CaptureOptions
from dcseg.io.captures.arkit import opencv_pose, quaternion_pose
from dcseg.io.captures.common import (
    RAW_CONFIDENCE_SUFFIX,
    RAW_DEPTH_SUFFIX,
    Camera,
    FrameSpec,
    Listing,
    add_if_present,
    warn_if_options_intrinsics,
)
from dcseg.io.captures.jsonfields import JsonFields, join, load_json

__all__ = [
    "METADATA",
    "METADATA_JSON",
    "R3D_SUFFIX",
    "RGBD",
    "list_exr_frames",
    "list_frames",
    "matches",
    "matches_exr",
]

METADATA = "metadata"
METADATA_JSON = "metadata.json"
RGBD = "rgbd"
R3D_SUFFIX = ".r3d"
"""A Record3D export file: a zip archive of this layout."""

_COLOUR = re.compile(r"(\d+)\.(jpg|jpeg|png)", re.IGNORECASE)
_POSE_LENGTH = 7


def matches(root: Path) -> bool:
    """Whether ``root`` has Record3D's ``metadata`` file and ``rgbd/`` folder (``.r3d``)."""
    return (root / METADATA).is_file() and (root / RGBD).is_dir()


def matches_exr(root: Path) -> bool:
    """Whether ``root`` has ``metadata.json``, ``rgb/`` and ``depth/`` ("EXR + JPG" export)."""
    folders = (root / _EXR.colour).is_dir() and (root / "depth").is_dir()
    return (root / METADATA_JSON).is_file() and folders


def _intrinsics(fields: JsonFields, doc: dict[str, Any]) -> Camera | None:
    value = fields.get(doc, "K", "")
    width, height = fields.integer(doc, "w", ""), fields.integer(doc, "h", "")
    if value is None:
        return None
    k = _numbers(fields, value, "K", 9, "a 3x3 camera matrix as 9 numbers, column-major")
    if k is None or width is None or height is None:
        return None
    return Camera(k[0], k[4], k[6], k[7], (width, height), f"{fields.shown}:K")


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


def _colour_files(folder: Path) -> list[tuple[int, Path]]:
    found = [(m, p) for p in folder.iterdir() if (m := _COLOUR.fullmatch(p.name))]
    return sorted((int(m.group(1)), p) for m, p in found)


def _header(
    fields: JsonFields, doc: dict[str, Any], raw: bool
) -> tuple[Camera | None, tuple[int, int] | None]:
    camera = _intrinsics(fields, doc)
    if not raw:  # the depth images state their own size
        return camera, None
    dw, dh = fields.integer(doc, "dw", ""), fields.integer(doc, "dh", "")
    return camera, (dw, dh) if dw is not None and dh is not None else None


def _poses(
    fields: JsonFields, doc: dict[str, Any], colour: list[tuple[int, Path]], folder: str
) -> list[NDArray[np.float64] | None]:
    value = fields.get(doc, "poses", "")
    items = fields.array(value, "poses") if value is not None else None
    if items is None:
        return []
    if len(items) != len(colour):
        fields.add(
            "poses", f"has {len(items)} poses but {folder}/ holds {len(colour)} colour images"
        )
    for index, rgb in colour:
        if index >= len(items):
            fields.add("poses", f"has no pose for {folder}/{rgb.name} (needs entry {index})")
    return [_pose(fields, item, join("poses", i)) for i, item in enumerate(items)]


@dataclass(frozen=True)
class _Export:
    """One of Record3D's exports: where its metadata, colour and depth are."""

    metadata: str
    colour: str
    depth: str | None  # the depth folder; None = beside the colour (``.r3d``)
    depth_suffix: str
    raw: bool  # depth/confidence are LZFSE buffers of the metadata's dw x dh


_R3D = _Export(METADATA, RGBD, None, RAW_DEPTH_SUFFIX, raw=True)
_EXR = _Export(METADATA_JSON, "rgb", "depth", ".exr", raw=False)


def _list(root: Path, options: CaptureOptions, export: _Export) -> Listing:
    warn_if_options_intrinsics(options, "Record3D")
    fields = JsonFields(export.metadata)
    doc = fields.mapping(load_json(root / export.metadata, export.metadata), "")
    if doc is None:
        fields.raise_if_any()
        return Listing()
    colour = _colour_files(root / export.colour)
    camera, raw_size = _header(fields, doc, export.raw)
    poses = _poses(fields, doc, colour, export.colour)
    fields.raise_if_any()
    assert camera is not None
    listing = Listing(resample_depth=True)
    for index, rgb in colour:
        pose = poses[index]
        assert pose is not None
        depth_folder = rgb.parent if export.depth is None else root / export.depth
        spec = FrameSpec(
            str(index),
            rgb,
            depth_folder / f"{index}{export.depth_suffix}",
            pose,
            camera,
            f"{export.metadata}:{join('poses', index)}",
            raw_size=raw_size,
            confidence=rgb.with_suffix(RAW_CONFIDENCE_SUFFIX) if export.raw else None,
        )
        add_if_present(listing, spec, root)
    return listing


def list_frames(root: Path, options: CaptureOptions) -> Listing:
    """List the frames of a Record3D ``.r3d`` export folder.

    Raises:
        InputError: ``metadata`` is not valid JSON, lacks a field, has a malformed one, or
            holds another number of poses than there are colour images (all problems at once).
    """
    return _list(root, options, _R3D)


def list_exr_frames(root: Path, options: CaptureOptions) -> Listing:
    """List the frames of a Record3D "EXR + JPG" export folder.

    Raises:
        InputError: as :func:`list_frames`, for ``metadata.json``.
    """
    return _list(root, options, _EXR)
