"""``poses.json``: the cameras a reconstruction fitted, where they differ from the capture's.

Written beside ``scene.ply`` by ``dcseg reconstruct`` and the worker's reconstruct stage when
poses are refined (``--refine-poses``), the depth was registered onto the colour with a
different colour camera (``sensor.registration``) or the intrinsics were corrected
(``sensor.intrinsics``); a run given that scene (``--scene``, the worker's train stage) reads
it so that its cache, features and maps see the scene from the cameras it was fitted to::

    {"format": "dcseg-poses", "version": 1,
     "poses": {"<frame name>": [[r00, r01, r02, tx], ..., [0, 0, 0, 1]], ...},
     "registration": {"scale": 0.9, "shift_px": [0.0, -1.5], "parallax_px_m": -12.0},
     "intrinsics": {"focal_scale": 0.9, "principal_shift_px": [1.0, 0.5], "at_size": [640, 480]}}

``registration`` and ``intrinsics`` are optional (:class:`dcseg.reconstruct.registration.
Registration`, :class:`dcseg.reconstruct.calibration.Correction`).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dcseg.errors import InputError

POSES_FILE = "poses.json"
FORMAT = "dcseg-poses"
VERSION = 1


@dataclass(frozen=True)
class CameraFile:
    """What ``poses.json`` holds: every frame's pose, and the registration and intrinsics
    correction records when the reconstruction applied them."""

    poses: dict[str, NDArray[np.float64]]
    registration: dict[str, Any] | None = field(default=None)
    intrinsics: dict[str, Any] | None = field(default=None)


def write_poses(
    path: Path,
    poses: Mapping[str, NDArray[np.float64] | list[list[float]]],
    registration: dict[str, Any] | None = None,
    intrinsics: dict[str, Any] | None = None,
) -> None:
    """Write ``poses`` (frame name -> 4x4 camera-to-world) and the optional records to
    ``path``."""
    doc: dict[str, Any] = {
        "format": FORMAT,
        "version": VERSION,
        "poses": {name: np.asarray(c2w, dtype=np.float64).tolist() for name, c2w in poses.items()},
    }
    for key, record in (("registration", registration), ("intrinsics", intrinsics)):
        if record is not None:
            doc[key] = record
    path.write_text(json.dumps(doc) + "\n", encoding="utf-8")


def read_cameras(path: Path) -> CameraFile:
    """The poses and records in ``path``; an InputError naming the file and field for a
    malformed one."""
    from dcseg.reconstruct.calibration import Correction
    from dcseg.reconstruct.registration import Registration

    doc = _document(path)
    records: dict[str, dict[str, Any] | None] = {}
    parsers = (("registration", Registration.of_record), ("intrinsics", Correction.of_record))
    for key, parse in parsers:
        record = doc.get(key)
        if record is not None:
            try:
                parse(record)
            except ValueError as exc:
                raise InputError.single(str(path), f'"{key}": {exc}') from exc
        records[key] = record
    return CameraFile(_poses(path, doc), records["registration"], records["intrinsics"])


def read_poses(path: Path) -> dict[str, NDArray[np.float64]]:
    """The poses in ``path``; an InputError naming the file for anything else."""
    return _poses(path, _document(path))


def _document(path: Path) -> dict[str, Any]:
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise InputError.single(str(path), f"cannot be read as JSON: {exc}") from exc
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise InputError.single(str(path), f'is not a poses file ("format": "{FORMAT}")')
    return doc


def _poses(path: Path, doc: dict[str, Any]) -> dict[str, NDArray[np.float64]]:
    poses = doc.get("poses")
    if not isinstance(poses, dict):
        raise InputError.single(str(path), '"poses" must map frame names to 4x4 poses')
    out: dict[str, NDArray[np.float64]] = {}
    for name, c2w in poses.items():
        try:
            matrix = np.asarray(c2w, dtype=np.float64)
        except (TypeError, ValueError):
            matrix = np.zeros(0)
        if matrix.shape != (4, 4) or not np.isfinite(matrix).all():
            raise InputError.single(str(path), f'pose of "{name}" must be a finite 4x4 matrix')
        out[name] = matrix
    return out
