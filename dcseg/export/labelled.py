"""A finished run's labelled Gaussians and object table, read without torch.

Reads ``scene_labelled.ply`` (columns by name: ``instance_id`` is the object id, 1-based,
-1 = none; ``semantic_id`` the class index, -1 = none; other integer columns are carried
along), ``instances.json`` (checked against the PLY's sha256), ``labels.json`` and ``run.json``.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dcseg.errors import InputError
from dcseg.export.errors import RunNotFinishedError, UnknownInstanceError
from dcseg.io.exports import sha256_file
from dcseg.io.splat_table import SplatTable, read_splat_table

INSTANCE_COLUMN = "instance_id"
CLASS_COLUMN = "semantic_id"
SCENE_FILE = "scene_labelled.ply"


@dataclass(frozen=True)
class LabelledRun:
    """What every export format starts from.

    Attributes:
        path: the run folder.
        splats: every Gaussian of ``scene_labelled.ply``.
        instances: the records of ``instances.json`` (``id``, ``label``, ``score`` ...), by id.
        classes: the vocabulary of ``labels.json``, by class index.
        record: ``run.json``.
    """

    path: Path
    splats: SplatTable
    instances: tuple[dict[str, Any], ...]
    classes: tuple[str, ...]
    record: dict[str, Any]

    @property
    def instance_ids(self) -> NDArray[np.int32]:
        """``[N]`` object id per Gaussian (-1 = none)."""
        return self.splats.ints[INSTANCE_COLUMN]

    @property
    def class_ids(self) -> NDArray[np.int32]:
        """``[N]`` class index per Gaussian (-1 = none); from the objects when the PLY has none."""
        if CLASS_COLUMN in self.splats.ints:
            return self.splats.ints[CLASS_COLUMN]
        table = {int(r["id"]): int(r.get("label_id", -1)) for r in self.instances}
        lookup = np.vectorize(lambda k: table.get(int(k), -1), otypes=[np.int32])
        out: NDArray[np.int32] = lookup(self.instance_ids)
        return out

    def select(self, ids: Sequence[int] | None) -> list[dict[str, Any]]:
        """The records of ``ids`` (all when None), in the order given.

        Raises:
            UnknownInstanceError: an id the run does not hold (all unknown ids are named).
        """
        if ids is None:
            return list(self.instances)
        by_id = {int(r["id"]): r for r in self.instances}
        unknown = [k for k in ids if k not in by_id]
        if unknown:
            known = _ranges(sorted(by_id))
            reason = f"unknown instance id(s) {unknown}; this run holds {known}"
            raise UnknownInstanceError.single("instances", reason)
        return [by_id[k] for k in dict.fromkeys(ids)]


def _ranges(ids: list[int]) -> str:
    if not ids:
        return "no instances"
    spans: list[str] = []
    start = prev = ids[0]
    for k in [*ids[1:], None]:
        if k is not None and k == prev + 1:
            prev = k
            continue
        spans.append(str(start) if start == prev else f"{start}-{prev}")
        if k is not None:
            start = prev = k
    return "ids " + ", ".join(spans)


def load_labelled_run(run: Path) -> LabelledRun:
    """Read a finished run folder.

    Raises:
        RunNotFinishedError: the folder is missing, not a run, or not segmented yet.
        InputError: a file is unreadable, or ``instances.json`` indexes another PLY.
    """
    _check_finished(run)
    ply = run / SCENE_FILE
    splats = read_splat_table(ply)
    if INSTANCE_COLUMN not in splats.ints:
        raise InputError.single(str(ply), f"no integer {INSTANCE_COLUMN!r} column")
    body = _read_json(run / "instances.json")
    if body.get("scene_sha256") not in (None, sha256_file(ply)):
        reason = f"scene_sha256 does not match {SCENE_FILE}: the table indexes another scene"
        raise InputError.single(str(run / "instances.json"), reason)
    labels = _read_json(run / "labels.json").get("labels", []) if _has(run, "labels.json") else []
    instances = tuple(sorted(body.get("instances", []), key=lambda r: int(r["id"])))
    return LabelledRun(
        path=run,
        splats=splats,
        instances=instances,
        classes=tuple(str(c["name"]) for c in labels),
        record=_read_json(run / "run.json"),
    )


def _has(run: Path, name: str) -> bool:
    return (run / name).is_file()


def _check_finished(run: Path) -> None:
    if not run.is_dir():
        raise RunNotFinishedError.single(str(run), "no such run folder")
    if not _has(run, "run.json"):
        reason = "not a finished dcseg run (no run.json; the run may still be going)"
        raise RunNotFinishedError.single(str(run), reason)
    missing = [n for n in (SCENE_FILE, "instances.json") if not _has(run, n)]
    if missing:
        reason = f"the run is not segmented (no {' or '.join(missing)}); run dcseg reclassify"
        raise RunNotFinishedError.single(str(run), reason)


def _read_json(path: Path) -> dict[str, Any]:
    try:
        body = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as error:
        raise InputError.single(str(path), f"cannot read JSON: {error}") from None
    if not isinstance(body, dict):
        raise InputError.single(str(path), "expected a JSON object")
    return body
