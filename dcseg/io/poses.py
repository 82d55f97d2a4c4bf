"""``poses.json``: the refined camera poses a reconstruction fitted (``--refine-poses``).

Written beside ``scene.ply`` by ``dcseg reconstruct`` and the worker's reconstruct stage when
poses are refined; a run given that scene (``--scene``, the worker's train stage) reads them
so that its cache, features and maps see the scene from the poses it was fitted to::

    {"format": "dcseg-poses", "version": 1,
     "poses": {"<frame name>": [[r00, r01, r02, tx], ..., [0, 0, 0, 1]], ...}}
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from dcseg.errors import InputError

POSES_FILE = "poses.json"
FORMAT = "dcseg-poses"
VERSION = 1


def write_poses(path: Path, poses: Mapping[str, NDArray[np.float64] | list[list[float]]]) -> None:
    """Write ``poses`` (frame name -> 4x4 camera-to-world) to ``path``."""
    doc = {
        "format": FORMAT,
        "version": VERSION,
        "poses": {name: np.asarray(c2w, dtype=np.float64).tolist() for name, c2w in poses.items()},
    }
    path.write_text(json.dumps(doc) + "\n", encoding="utf-8")


def read_poses(path: Path) -> dict[str, NDArray[np.float64]]:
    """The poses in ``path``; an InputError naming the file for anything else."""
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise InputError.single(str(path), f"cannot be read as JSON: {exc}") from exc
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise InputError.single(str(path), f'is not a poses file ("format": "{FORMAT}")')
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
