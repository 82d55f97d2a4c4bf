"""Exports of a finished run for apps, engines and viewers: per-object Gaussians, compact splat
formats, meshes, and the coordinate frame they are in.

``export_run(run, out, fmt)`` writes into ``out``:

* ``ply``: ``instance_<k>.ply`` per object (the INRIA 3DGS layout, floats only); for a
  whole-run export also ``scene.ply`` (grouped by object), ``scene.labels.npy`` (its labels),
  ``scene_labelled.ply`` (integer columns kept), ``scene_by_instance.ply`` and
  ``scene_by_class.ply`` (palette colours in the DC term);
* ``spz`` / ``splat``: ``instance_<k>.spz|splat`` per object, and ``scene.spz|splat`` (SPZ in
  its RUB axes);
* ``glb``: ``instance_<k>.glb`` per object and ``scene.glb``: Gaussians with the Khronos
  ``KHR_gaussian_splatting`` extension, one node per object (name, class, score in the node's
  ``extras``), in glTF's Y-up;
* ``glb-mesh``: ``scene_mesh.glb``, one mesh node per object, meshed from the run's depth,
  turned to glTF's Y-up;
* ``obj``: ``instance_<k>.obj`` per object and ``scene_mesh.ply`` (vertex colours and an
  ``instance_id`` per vertex);
* ``usdz``: ``instance_<k>.usdz`` per object and ``scene.usdz``: the meshes for AR Quick Look;

and always ``instances.<fmt>.json`` (the objects' records, each with its file, palette colour
and, for Gaussian scene files, ``[offset, count]``) and ``frame.json`` (see
:mod:`dcseg.export.frame`). Importing this package, and the Gaussian formats (``glb`` too),
need no torch.
"""

from __future__ import annotations

import importlib
import os
import shutil
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Protocol

from dcseg.export.errors import (
    ExportError,
    RunNotFinishedError,
    UnknownFormatError,
    UnknownInstanceError,
)
from dcseg.export.options import ExportOptions
from dcseg.export.plan import ExportPlan, Written

__all__ = [
    "FORMATS",
    "ExportError",
    "ExportOptions",
    "RunNotFinishedError",
    "UnknownFormatError",
    "UnknownInstanceError",
    "export_run",
]

_WRITERS = {
    "ply": "dcseg.export.gaussians:write_gaussians",
    "spz": "dcseg.export.gaussians:write_gaussians",
    "splat": "dcseg.export.gaussians:write_gaussians",
    "glb": "dcseg.export.gaussians:write_glb_splats",
    "glb-mesh": "dcseg.export.meshes:write_meshes",
    "obj": "dcseg.export.meshes:write_meshes",
    "usdz": "dcseg.export.usdz:write_usdz_meshes",
}
"""Format -> the writer ``module:function`` (imported on use: meshes pull in trimesh, numba)."""

FORMATS: tuple[str, ...] = tuple(_WRITERS)


def export_run(
    run: Path,
    out: Path,
    fmt: str,
    *,
    instances: Sequence[int] | None = None,
    options: ExportOptions | None = None,
) -> list[Path]:
    """Export a finished run in one format; returns the files written (in ``out``).

    Files are written into a temporary folder inside ``out`` and moved into place at the end,
    so a failed export leaves no partial files (earlier exports in ``out`` stay as they were).

    Args:
        run: a finished run folder (``run.json``, ``scene_labelled.ply``, ``instances.json``).
        out: the folder to write into (created if missing).
        fmt: one of :data:`FORMATS`.
        instances: object ids to export (None = every object, plus scene-wide files).
        options: colours, SH degree, mesh settings (defaults: :class:`ExportOptions`).

    Raises:
        UnknownFormatError: ``fmt`` is not in :data:`FORMATS`.
        RunNotFinishedError: ``run`` is missing, still running, or not segmented.
        UnknownInstanceError: an id in ``instances`` is not one of the run's objects.
        InputError: a file of the run is unreadable, or a mesh needs depth the run lacks.
    """
    from dcseg.export.labelled import load_labelled_run
    from dcseg.export.sidecars import write_sidecars

    if fmt not in _WRITERS:
        reason = f"unknown export format {fmt!r}; choose one of {', '.join(FORMATS)}"
        raise UnknownFormatError.single("format", reason)
    options = options or ExportOptions()
    labelled = load_labelled_run(Path(run))
    records = labelled.select(instances)
    plan = ExportPlan(labelled, records, instances is None, options)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".export-", dir=out))  # one per call, threads too
    try:
        written = _writer(fmt)(plan, tmp, fmt)
        names = [*written.files, *write_sidecars(plan, tmp, fmt, written)]
        for name in names:
            os.replace(tmp / name, out / name)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return [out / name for name in names]


def _writer(fmt: str) -> _Writer:
    module, name = _WRITERS[fmt].split(":")
    writer: _Writer = getattr(importlib.import_module(module), name)
    return writer


class _Writer(Protocol):
    """What every format writer is: write ``plan`` in ``fmt`` into ``folder``."""

    def __call__(self, plan: ExportPlan, folder: Path, fmt: str) -> Written: ...
