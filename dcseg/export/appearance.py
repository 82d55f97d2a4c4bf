"""Colours and SH degree of exported Gaussians: palette colours any viewer shows, SH padding."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from dcseg.export.labelled import LabelledRun
from dcseg.export.options import ExportOptions
from dcseg.io.exports import palette
from dcseg.io.splat_table import SH_C0, SplatTable

NONE_RGB = (128, 128, 128)
"""Colour of Gaussians without an object or class (mid grey)."""


def palette_colours(ids: NDArray[np.integer[Any]], first: int, n: int) -> NDArray[np.uint8]:
    """``[N, 3]`` RGB of ids ``first .. first + n - 1`` (the colours of ``preview.png``); any
    other id (-1 = none) is :data:`NONE_RGB`."""
    table = np.concatenate([palette(max(n, 1)), np.array([NONE_RGB], np.uint8)])
    index = np.asarray(ids, np.int64) - first
    index = np.where((index >= 0) & (index < n), index, len(table) - 1)
    out: NDArray[np.uint8] = table[index]
    return out


def object_colours(run: LabelledRun, rows: NDArray[Any] | None = None) -> NDArray[np.uint8]:
    """Palette colour of each Gaussian's object (ids start at 1)."""
    ids = run.instance_ids if rows is None else run.instance_ids[rows]
    n = max((int(r["id"]) for r in run.instances), default=0)
    return palette_colours(ids, 1, n)


def class_colours(run: LabelledRun, rows: NDArray[Any] | None = None) -> NDArray[np.uint8]:
    """Palette colour of each Gaussian's class (indices start at 0)."""
    ids = run.class_ids if rows is None else run.class_ids[rows]
    return palette_colours(ids, 0, len(run.classes))


PALETTES = {"instance": object_colours, "class": class_colours}
"""Colour mode -> the palette colour of each Gaussian."""


def gaussian_rgb(table: SplatTable) -> NDArray[np.uint8]:
    """``[N, 3]`` view-independent colour (the SH DC term) of each Gaussian."""
    rgb = np.clip(0.5 + SH_C0 * table.sh[:, 0, :], 0.0, 1.0)
    out: NDArray[np.uint8] = np.round(rgb * 255.0).astype(np.uint8)
    return out


def paint(table: SplatTable, rgb: NDArray[np.uint8]) -> SplatTable:
    """``table`` with SH degree 0 whose colour is ``rgb`` (``f_dc = (rgb - 0.5) / SH_C0``)."""
    dc = ((rgb.astype(np.float32) / 255.0 - 0.5) / SH_C0).reshape(len(table), 1, 3)
    return SplatTable(
        table.means, table.quats, table.log_scales, table.opacity_logits, dc, table.ints
    )


def with_sh_degree(table: SplatTable, degree: int) -> SplatTable:
    """``table`` with exactly ``(degree + 1)^2`` SH coefficients: zeros appended, or the higher
    bands dropped."""
    coeffs = (degree + 1) ** 2
    have = table.sh.shape[1]
    if have >= coeffs:
        sh = table.sh[:, :coeffs, :]
    else:
        pad = np.zeros((len(table), coeffs - have, 3), np.float32)
        sh = np.concatenate([table.sh, pad], axis=1)
    return SplatTable(
        table.means, table.quats, table.log_scales, table.opacity_logits, sh, table.ints
    )


def styled(run: LabelledRun, rows: NDArray[Any], options: ExportOptions) -> SplatTable:
    """The Gaussians at ``rows`` with the colours and SH degree ``options`` ask for."""
    table = run.splats.take(rows)
    if options.colour is not None:
        table = paint(table, PALETTES[options.colour](run, rows))
    if options.sh_degree is not None:
        table = with_sh_degree(table, options.sh_degree)
    return table
