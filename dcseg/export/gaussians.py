"""Gaussian formats (PLY, SPZ, .splat): one file per selected object, and for a whole-run
export one scene file whose Gaussians are grouped by object (``instances.json`` gives each
object's ``[offset, count]``). PLY files are the INRIA layout, floats only, SH degree 3 unless
asked otherwise (:mod:`dcseg.export.ply_file`); a whole-run PLY export also gets
``scene.labels.npy`` (the labels of ``scene.ply``'s Gaussians), ``scene_labelled.ply`` (the
run's integer columns kept) and ``scene_by_instance.ply`` / ``scene_by_class.ply``: palette
colours in the DC term, so any splat viewer shows the segmentation without custom code."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dcseg.export.appearance import styled
from dcseg.export.axes import gltf_frame, gltf_turn, turned
from dcseg.export.gltf_splats import write_splat_glb
from dcseg.export.options import ExportOptions
from dcseg.export.plan import ExportPlan, Written, node_extras
from dcseg.export.ply_file import (
    INRIA_SH_DEGREE,
    LABELLED_SCENE,
    labels_name,
    write_inria_ply,
    write_labels,
)
from dcseg.export.splat_file import write_splat
from dcseg.export.spz_file import write_spz
from dcseg.io.splat_table import SplatTable, write_splat_table

Encoder = Callable[[Path, SplatTable, ExportOptions], None]


def _write_ply(path: Path, table: SplatTable, options: ExportOptions) -> None:
    write_inria_ply(path, table)


ENCODERS: dict[str, tuple[str, Encoder]] = {
    "ply": ("ply", _write_ply),
    "spz": ("spz", write_spz),
    "splat": ("splat", write_splat),
}
"""Format name -> (file extension, encoder)."""

GLTF_AXES = frozenset({"spz"})
"""Formats whose specification fixes the axes (SPZ: RUB, glTF's): turned by ``frame.json``'s
matrix (:mod:`dcseg.export.axes`); PLY and .splat keep world coordinates, as 3DGS tools expect."""

PALETTE_SCENES = {"instance": "scene_by_instance.ply", "class": "scene_by_class.ply"}


def write_gaussians(plan: ExportPlan, folder: Path, fmt: str) -> Written:
    """Write ``plan``'s Gaussians in ``fmt`` (a key of :data:`ENCODERS`) into ``folder``."""
    ext, encode = ENCODERS[fmt]
    options = resolved(fmt, plan.options)
    turn = gltf_turn(plan.run.path, options.capture) if fmt in GLTF_AXES else None

    def table_of(rows: NDArray[Any], options: ExportOptions = options) -> SplatTable:
        table = styled(plan.run, rows, options)
        return table if turn is None else turned(table, turn)

    written = Written()
    for k in plan.ids:
        name = f"instance_{k}.{ext}"
        encode(folder / name, table_of(plan.rows_of(k)), options)
        written.files.append(name)
        written.per_instance[k] = name
    if not plan.whole:
        return written
    rows, written.ranges = plan.scene_rows()
    written.scene = f"scene.{ext}"
    scene = table_of(rows)
    encode(folder / written.scene, scene, options)
    written.files.append(written.scene)
    if fmt == "ply":
        _ply_scene_extras(plan, folder, written, scene, rows)
    return written


def resolved(fmt: str, options: ExportOptions) -> ExportOptions:
    """``options`` with PLY's default SH degree (:data:`INRIA_SH_DEGREE`) filled in."""
    if fmt != "ply" or options.sh_degree is not None:
        return options
    return replace(options, sh_degree=INRIA_SH_DEGREE)


def _ply_scene_extras(
    plan: ExportPlan, folder: Path, written: Written, scene: SplatTable, rows: Any
) -> None:
    """The labels of ``scene.ply``, the labelled scene, and the palette scenes."""
    labels = labels_name(f"scene.{ENCODERS['ply'][0]}")
    written.labels = write_labels(folder / labels, scene)
    write_splat_table(folder / LABELLED_SCENE, styled(plan.run, rows, plan.options))
    written.files += [labels, LABELLED_SCENE]
    options = resolved("ply", plan.options)
    for mode, name in PALETTE_SCENES.items():
        painted = replace(options, colour=mode)  # type: ignore[arg-type]
        write_inria_ply(folder / name, styled(plan.run, rows, painted))
        written.files.append(name)


UNASSIGNED_NODE = {"instance_id": -1, "name": "unassigned", "label": None, "class": None}
"""The extras of the scene GLB's node holding the Gaussians of no object."""


def write_glb_splats(plan: ExportPlan, folder: Path, fmt: str) -> Written:
    """``instance_<k>.glb`` per object and, for a whole run, ``scene.glb`` (one node per object
    and one ``unassigned``): ``KHR_gaussian_splatting`` in glTF's axes
    (:mod:`dcseg.export.gltf_splats`)."""
    run, options = plan.run, plan.options
    frame = gltf_frame(run.path, options.capture, ["baked into every Gaussian (no node matrix)"])
    turn = np.asarray(frame["to_gltf"]["matrix"], np.float64)[:3, :3]
    extras = {"dcseg_frame": frame}
    records = {int(r["id"]): r for r in plan.records}

    def node(k: int) -> tuple[dict[str, Any], SplatTable]:
        return node_extras(records[k]), turned(styled(run, plan.rows_of(k), options), turn)

    written = Written()
    nodes = [node(k) for k in plan.ids]
    for k, pair in zip(plan.ids, nodes, strict=True):
        name = f"instance_{k}.glb"
        write_splat_glb(folder / name, [pair], extras)
        written.files.append(name)
        written.per_instance[k] = name
        if len(pair[1]):
            written.nodes[k] = pair[0]["name"]
    if plan.whole:
        rest = np.flatnonzero(~np.isin(run.instance_ids, plan.ids))
        nodes.append((dict(UNASSIGNED_NODE), turned(styled(run, rest, options), turn)))
        written.scene = "scene.glb"
        write_splat_glb(folder / written.scene, nodes, extras)
        written.files.append(written.scene)
    return written
