"""PLY Gaussians in exactly the INRIA 3DGS layout, with the labels beside them.

Every exported Gaussian PLY holds one binary little-endian ``vertex`` element of float32
properties only, in the reference implementation's order::

    x y z nx ny nz f_dc_0..2 f_rest_0..(3K-4) opacity scale_0..2 rot_0..3

(K = SH coefficients per channel; SH degree 3 by default, K = 16: 62 floats, 248 bytes per
Gaussian), so loaders that read fixed records (SIBR, the INRIA viewer, engine importers) read
every Gaussian. The integer labels a run keeps per Gaussian (``instance_id``, ``semantic_id``,
``cluster_id``) cannot go in that record; they go to ``<stem>.labels.npy`` beside the scene
file: an int32 ``[N, C]`` array, one row per Gaussian in the file's order, the columns named by
:data:`LABEL_COLUMNS` order and by ``instances.ply.json`` (``labels.columns``). The run's own
columns are also kept in ``scene_labelled.ply`` (3DGS floats then int32 columns, as before).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from dcseg.io.splat_table import SplatTable, write_splat_table

INRIA_SH_DEGREE = 3
"""SH degree of PLY exports unless ``--sh-degree`` says otherwise (45 ``f_rest_*``)."""
LABEL_COLUMNS = ("instance_id", "semantic_id", "cluster_id")
"""Preferred order of the label columns (others the run holds follow, by name)."""
LABELLED_SCENE = "scene_labelled.ply"
"""The scene with the run's integer columns kept (the layout before INRIA-only PLYs)."""


def labels_name(ply_name: str) -> str:
    """``scene.ply`` -> ``scene.labels.npy``."""
    return f"{Path(ply_name).stem}.labels.npy"


def floats_only(table: SplatTable) -> SplatTable:
    """``table`` without its integer columns."""
    return SplatTable(
        table.means, table.quats, table.log_scales, table.opacity_logits, table.sh, {}
    )


def write_inria_ply(path: Path, table: SplatTable) -> None:
    """Write ``table``'s float properties only, in the INRIA order."""
    write_splat_table(path, floats_only(table))


def label_columns(table: SplatTable) -> list[str]:
    """The integer columns of ``table``: :data:`LABEL_COLUMNS` first, then the rest by name."""
    known = [name for name in LABEL_COLUMNS if name in table.ints]
    return known + sorted(set(table.ints) - set(known))


def write_labels(path: Path, table: SplatTable) -> dict[str, Any]:
    """Write ``table``'s integer columns as an int32 ``[N, C]`` ``.npy``; returns its
    description for ``instances.ply.json``."""
    columns = label_columns(table)
    stacked = np.zeros((len(table), len(columns)), np.int32)
    for i, name in enumerate(columns):
        stacked[:, i] = table.ints[name]
    np.save(path, stacked, allow_pickle=False)
    return {
        "file": path.name,
        "columns": columns,
        "layout": "int32 [N, C] .npy, row i = Gaussian i of the scene file (and of the "
        "scene_by_*.ply palette scenes); -1 = none",
    }
