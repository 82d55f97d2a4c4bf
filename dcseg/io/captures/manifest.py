"""The dcseg capture manifest: dcseg's own layout, read and written losslessly.

A capture folder holds ``capture.json`` and the image files it names::

    capture.json
    rgb/000000.png        colour, 8-bit RGB (PNG or JPEG)
    depth/000000.png      depth, 16-bit PNG (value / depth_scale = metres) or .npy float32 metres

``capture.json``::

    {
      "format": "dcseg.capture",
      "version": 1,
      "depth_scale": 1000.0,
      "intrinsics": {"fx": 525.0, "fy": 525.0, "cx": 319.5, "cy": 239.5,
                     "width": 640, "height": 480},
      "frames": [
        {"name": "000000",
         "rgb": "rgb/000000.png",
         "depth": "depth/000000.png",
         "c2w": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]],
         "intrinsics": {"fx": ..., "fy": ..., "cx": ..., "cy": ..., "width": ..., "height": ...}}
      ]
    }

Fields:

* ``format`` must be ``"dcseg.capture"`` and ``version`` must be ``1``.
* ``depth_scale`` (optional, default 1000): a stored 16-bit depth value divided by it gives
  metres; 0 means "no depth". ``.npy`` depth files hold float32 metres and ignore it.
* ``intrinsics``: pinhole parameters in pixels of the colour image, with OpenCV's pixel-centre
  convention (the centre of the top-left pixel is (0, 0)); ``width``/``height`` must equal the
  colour image size. It may be omitted when every frame gives its own ``intrinsics``.
* ``frames``: in capture order. ``name`` is unique and is the stem 2D masks are matched by
  (it may contain ``/``, e.g. ``seq-01/frame-000000``); ``rgb`` and ``depth`` are paths relative
  to the folder and must stay inside it; ``c2w`` is the 4x4 camera-to-world pose, row-major
  (the top 3x4 block alone is accepted too), OpenCV camera axes (x right, y down, z forward),
  metres; it must be rigid (orthonormal rotation, det +1); the optional per-frame
  ``intrinsics`` overrides the global one.

Depth and colour of a frame must have the same size. Every problem is reported with the JSON
path at fault, e.g. ``capture.json: frames[3].c2w: missing``.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dcseg.config import CaptureOptions
from dcseg.errors import InputError
from dcseg.io.captures.common import (
    Camera,
    FrameSpec,
    Listing,
    add_if_present,
    warn_if_options_intrinsics,
)
from dcseg.io.captures.jsonfields import JsonFields, join, load_json
from dcseg.io.images import write_image
from dcseg.types import Capture, Frame, Intrinsics

__all__ = ["FORMAT", "MANIFEST", "VERSION", "list_frames", "write_capture"]

MANIFEST = "capture.json"
FORMAT = "dcseg.capture"
VERSION = 1
_DEPTH_SCALE = 1000.0
_MAX_PNG_DEPTH = 65535 / _DEPTH_SCALE
_SAFE_NAME = re.compile(r"[A-Za-z0-9_.-]+(/[A-Za-z0-9_.-]+)*")
_INTRINSIC_KEYS = ("fx", "fy", "cx", "cy")


def _camera(fields: JsonFields, value: Any, where: str) -> Camera | None:
    obj = fields.mapping(value, where)
    if obj is None:
        return None
    numbers = [fields.number(obj, key, where) for key in _INTRINSIC_KEYS]
    width, height = fields.integer(obj, "width", where), fields.integer(obj, "height", where)
    if None in numbers or width is None or height is None:
        return None
    fx, fy, cx, cy = (float(n) for n in numbers if n is not None)
    return Camera(fx, fy, cx, cy, (width, height), f"{MANIFEST}:{where}")


def _header(fields: JsonFields, doc: dict[str, Any]) -> tuple[float, Camera | None]:
    if doc.get("format") != FORMAT:
        fields.add("format", f"must be {FORMAT!r}, got {doc.get('format')!r}")
    if doc.get("version") != VERSION:
        fields.add("version", f"must be {VERSION}, got {doc.get('version')!r}")
    scale = fields.number(doc, "depth_scale", "", required=False)
    if scale is not None and scale <= 0:
        fields.add("depth_scale", f"must be > 0, got {scale}")
    camera = _camera(fields, doc["intrinsics"], "intrinsics") if "intrinsics" in doc else None
    return scale or _DEPTH_SCALE, camera


def _frame(
    fields: JsonFields, root: Path, item: Any, where: str, defaults: tuple[float, Camera | None]
) -> FrameSpec | None:
    obj = fields.mapping(item, where)
    if obj is None:
        return None
    name = fields.string(obj, "name", where)
    rgb = fields.relative_file(root, fields.string(obj, "rgb", where), join(where, "rgb"))
    depth = fields.relative_file(root, fields.string(obj, "depth", where), join(where, "depth"))
    c2w = fields.matrix4(obj, "c2w", where)
    camera = defaults[1]
    if "intrinsics" in obj:
        camera = _camera(fields, obj["intrinsics"], join(where, "intrinsics"))
    elif camera is None:
        fields.add(join(where, "intrinsics"), "missing (and no global intrinsics)")
    if name is None or rgb is None or depth is None or c2w is None or camera is None:
        return None
    pose_source = f"{MANIFEST}:{join(where, 'c2w')}"
    return FrameSpec(name, rgb, depth, c2w, camera, pose_source, depth_scale=defaults[0])


def list_frames(root: Path, options: CaptureOptions) -> Listing:
    """List the frames of a dcseg manifest folder.

    Raises:
        InputError: ``capture.json`` is not valid JSON or breaks the schema (all problems).
    """
    warn_if_options_intrinsics(options, "dcseg")
    fields = JsonFields(MANIFEST)
    doc = fields.mapping(load_json(root / MANIFEST, MANIFEST), "")
    if doc is None:
        raise InputError(fields.problems)
    defaults = _header(fields, doc)
    value = fields.get(doc, "frames", "")
    items = fields.array(value, "frames") if value is not None else None
    specs = [
        _frame(fields, root, item, join("frames", i), defaults)
        for i, item in enumerate(items or [])
    ]
    fields.raise_if_any()
    listing = Listing()
    for spec in specs:
        if spec is not None:
            add_if_present(listing, spec, root)
    return listing


def _intrinsics_json(k: Intrinsics) -> dict[str, float | int]:
    return {"fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy, "width": k.width, "height": k.height}


def _file_stems(frames: tuple[Frame, ...]) -> list[str]:
    """Unique file stems: the frame name when it is a safe relative path, else its index."""
    stems: list[str] = []
    used: set[str] = set()
    for index, frame in enumerate(frames):
        name = frame.name
        safe = _SAFE_NAME.fullmatch(name) and not {".", ".."} & set(name.split("/"))
        stem = name if safe and name not in used else f"{index:06d}"
        while stem in used:
            stem = f"_{stem}"
        used.add(stem)
        stems.append(stem)
    return stems


def _write_depth(folder: Path, stem: str, depth: NDArray[np.float32]) -> str:
    if float(depth.max(initial=0.0)) <= _MAX_PNG_DEPTH:
        raw = np.rint(depth.astype(np.float64) * _DEPTH_SCALE).astype(np.uint16)
        return write_image(folder / "depth" / f"{stem}.png", raw).relative_to(folder).as_posix()
    path = folder / "depth" / f"{stem}.npy"
    path.parent.mkdir(parents=True, exist_ok=True)
    np.save(path, depth.astype(np.float32), allow_pickle=False)
    return path.relative_to(folder).as_posix()


def _frame_json(frame: Frame, stem: str, folder: Path, k: Intrinsics) -> dict[str, Any]:
    rgb = write_image(folder / "rgb" / f"{stem}.png", frame.rgb).relative_to(folder).as_posix()
    item: dict[str, Any] = {
        "name": frame.name,
        "rgb": rgb,
        "depth": _write_depth(folder, stem, frame.depth),
        "c2w": [[float(v) for v in row] for row in frame.c2w],
    }
    if frame.intrinsics != k:
        item["intrinsics"] = _intrinsics_json(frame.intrinsics)
    return item


def write_capture(capture: Capture, folder: Path) -> Path:
    """Write ``capture`` as a dcseg manifest folder that :func:`read_capture` reads back.

    Colour is written as PNG (exact); depth as 16-bit PNG in millimetres (within 0.5 mm), or as
    float32 ``.npy`` for frames with depth beyond 65.535 m. Frame names that are not plain
    file names become ``000000``-style file names (the ``name`` field keeps the original).

    Args:
        capture: the capture to write.
        folder: the destination folder (created if missing; existing files are overwritten).

    Returns:
        The path of the written ``capture.json``.

    Raises:
        ValueError: the capture is RGB-only (the manifest has no place for its sparse points,
            and its all-0 depth would read back as a capture with depth and none valid).

    Example:
        >>> manifest = write_capture(capture, Path("out/scene"))  # doctest: +SKIP
    """
    if not capture.has_depth:
        raise ValueError("an RGB-only capture cannot be written as a dcseg manifest (no depth)")
    folder.mkdir(parents=True, exist_ok=True)
    k = capture.frames[0].intrinsics
    doc = {
        "format": FORMAT,
        "version": VERSION,
        "depth_scale": _DEPTH_SCALE,
        "intrinsics": _intrinsics_json(k),
        "frames": [
            _frame_json(frame, stem, folder, k)
            for frame, stem in zip(capture.frames, _file_stems(capture.frames), strict=True)
        ],
    }
    path = folder / MANIFEST
    path.write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
    return path
