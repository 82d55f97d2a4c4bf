"""Gaussian formats (PLY, SPZ, .splat): one file per selected object, and for a whole-run
export one scene file whose Gaussians are grouped by object (``instances.json`` gives each
object's ``[offset, count]``). PLY exports also get ``scene_by_instance.ply`` and
``scene_by_class.ply``: palette colours in the DC term, so any splat viewer shows the
segmentation without custom code."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

from dcseg.export.appearance import styled
from dcseg.export.options import ExportOptions
from dcseg.export.plan import ExportPlan, Written
from dcseg.export.splat_file import write_splat
from dcseg.export.spz_file import write_spz
from dcseg.io.splat_table import SplatTable, write_splat_table

Encoder = Callable[[Path, SplatTable, ExportOptions], None]


def _write_ply(path: Path, table: SplatTable, options: ExportOptions) -> None:
    write_splat_table(path, table)


ENCODERS: dict[str, tuple[str, Encoder]] = {
    "ply": ("ply", _write_ply),
    "spz": ("spz", write_spz),
    "splat": ("splat", write_splat),
}
"""Format name -> (file extension, encoder)."""

PALETTE_SCENES = {"instance": "scene_by_instance.ply", "class": "scene_by_class.ply"}


def write_gaussians(plan: ExportPlan, folder: Path, fmt: str) -> Written:
    """Write ``plan``'s Gaussians in ``fmt`` (a key of :data:`ENCODERS`) into ``folder``."""
    ext, encode = ENCODERS[fmt]
    written = Written()
    for k in plan.ids:
        name = f"instance_{k}.{ext}"
        encode(folder / name, styled(plan.run, plan.rows_of(k), plan.options), plan.options)
        written.files.append(name)
        written.per_instance[k] = name
    if not plan.whole:
        return written
    rows, written.ranges = plan.scene_rows()
    written.scene = f"scene.{ext}"
    encode(folder / written.scene, styled(plan.run, rows, plan.options), plan.options)
    written.files.append(written.scene)
    if fmt == "ply":
        for mode, name in PALETTE_SCENES.items():
            options = replace(plan.options, colour=mode)  # type: ignore[arg-type]
            write_splat_table(folder / name, styled(plan.run, rows, options))
            written.files.append(name)
    return written
