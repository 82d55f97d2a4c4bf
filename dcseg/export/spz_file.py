"""Niantic SPZ files through ``gsply`` (the compressed splat format Spark, PlayCanvas, Babylon,
Unity and Niantic's own tools read).

SPZ quantises: positions to 24-bit fixed point with 12 fractional bits (0.24 mm steps, +-2 km),
colours (SH DC) to 8 bits over +-3.33, log scales to 1/16, opacity to 8 bits of alpha, higher SH
coefficients to 8 bits over +-1, rotations to the smallest-three 32-bit code. SPZ stores RUB
(x right, y up, z back: glTF's axes); the tables given here are already turned there by
``frame.json``'s matrix (:mod:`dcseg.export.gaussians`), and ``gsply`` writes them as they are.
"""

from __future__ import annotations

from pathlib import Path

import gsply
import numpy as np

from dcseg.export.options import ExportOptions
from dcseg.io.splat_table import SplatTable


def to_gsdata(table: SplatTable) -> gsply.GSData:
    """``table`` as a ``gsply`` container in PLY conventions (log scales, logit opacities)."""
    rest = np.ascontiguousarray(table.sh[:, 1:, :])  # [N, 0, 3] for degree 0
    return gsply.GSData(
        means=np.ascontiguousarray(table.means),
        scales=np.ascontiguousarray(table.log_scales),
        quats=np.ascontiguousarray(table.quats),
        opacities=np.ascontiguousarray(table.opacity_logits),
        sh0=np.ascontiguousarray(table.sh[:, 0, :]),
        shN=rest,
    )


def write_spz(path: Path, table: SplatTable, options: ExportOptions) -> None:
    """Write ``table`` as an SPZ file (container version ``options.spz_version``)."""
    gsply.write_spz(path, to_gsdata(table), version=options.spz_version)
