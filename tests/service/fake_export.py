"""A stand-in for ``dcseg.export.export_run`` with its contract, for the service's export tests.

It runs in the export child process, so the test steers it through the environment (inherited
by the spawned child): ``FAKE_EXPORT_LOG`` (a file it appends one line to per call),
``FAKE_EXPORT_MODE`` = ``sleep`` (for ``FAKE_EXPORT_SLEEP_S``), ``invalid`` (an InputError
naming the run's path), ``crash`` (the process dies) or ``raise`` (an unexpected error).
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from plyfile import PlyData

from dcseg.errors import InputError


def export_run(
    run: Path,
    out: Path,
    fmt: str,
    *,
    instances: Sequence[int] | None = None,
    options: Any = None,
) -> list[Path]:
    """One file per selected instance (its Gaussians' rows), plus ``scene.<fmt>`` when whole."""
    _misbehave(run)
    ids = np.asarray(PlyData.read(str(run / "scene_labelled.ply"))["vertex"]["instance_id"])
    records = json.loads((run / "instances.json").read_text(encoding="utf-8"))["instances"]
    chosen = [int(r["id"]) for r in records] if instances is None else list(instances)
    written = []
    for k in chosen:
        rows = np.flatnonzero(ids == k).tolist()
        written.append(_write(out / "objects" / f"{k}.{fmt}", {"id": k, "rows": rows}))
    if instances is None:
        written.append(_write(out / f"scene.{fmt}", {"ids": chosen, "n": int(len(ids))}))
    return written


def _write(path: Path, body: dict[str, Any]) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(body), encoding="utf-8")
    return path


def _misbehave(run: Path) -> None:
    log = os.environ.get("FAKE_EXPORT_LOG")
    if log:
        with open(log, "a", encoding="utf-8") as handle:
            handle.write("call\n")
    mode = os.environ.get("FAKE_EXPORT_MODE", "")
    if mode == "sleep":
        time.sleep(float(os.environ.get("FAKE_EXPORT_SLEEP_S", "3")))
    elif mode == "invalid":
        raise InputError.single(str(run / "state"), f"no depth under {run}")
    elif mode == "crash":
        os._exit(3)
    elif mode == "raise":
        raise RuntimeError(f"boom at {run}")
