"""SAM ``amg.py`` folder output: ``<stem>/metadata.csv`` and one binary PNG ``<id>.png`` per mask.

The ``id`` column of ``metadata.csv`` lists the masks, in file order; each PNG is 0/255 (any
non-zero value is inside). All PNGs of a frame must have one size.
"""

from __future__ import annotations

import csv
import logging
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from dcseg.errors import InputError, Problem
from dcseg.io.images import display_path, read_image
from dcseg.io.mask_formats.rle import RLE, encode
from dcseg.types import AgnosticMasks

__all__ = ["METADATA_FILE", "read_png_folder"]

logger = logging.getLogger(__name__)

METADATA_FILE = "metadata.csv"


def read_png_folder(folder: Path, stem: str, root: Path) -> AgnosticMasks:
    """Read a SAM amg.py output folder: ``metadata.csv`` plus one binary PNG per mask id."""
    ids = _metadata_ids(folder / METADATA_FILE, display_path(folder / METADATA_FILE, root))
    rles: list[RLE] = []
    problems: list[Problem] = []
    first: tuple[str, tuple[int, ...]] | None = None
    for mask_id in ids:
        png = folder / f"{mask_id}.png"
        try:
            mask = _read_binary_png(png, root)
        except InputError as err:
            problems.extend(err.problems)
            continue
        if first is not None and mask.shape != first[1]:
            reason = _png_size_mismatch(mask.shape, first)
            problems.append(Problem(display_path(png, root), reason))
        else:
            first = first or (f"{mask_id}.png", mask.shape)
            if mask.any():
                rles.append(encode(mask))
    if problems:
        raise InputError(problems)
    if len(ids) > len(rles):
        logger.debug("%s: dropped %d empty mask(s)", stem, len(ids) - len(rles))
    height, width = first[1] if first is not None else (0, 0)
    return AgnosticMasks(stem, height, width, tuple(rles), display_path(folder, root))


def _png_size_mismatch(shape: tuple[int, ...], first: tuple[str, tuple[int, ...]]) -> str:
    return (
        f"mask is {shape[1]}x{shape[0]} but {first[0]} in the same folder is "
        f"{first[1][1]}x{first[1][0]}"
    )


def _metadata_ids(path: Path, shown: str) -> list[str]:
    """The mask ids listed in a SAM ``metadata.csv`` (its ``id`` column), in file order."""
    if not path.is_file():
        raise InputError.single(shown, "metadata.csv not found (SAM amg.py writes it)")
    try:
        with path.open(newline="", encoding="utf-8") as handle:
            rows = list(csv.DictReader(handle))
    except (OSError, UnicodeDecodeError, csv.Error) as err:
        raise InputError.single(shown, f"cannot read metadata: {err}") from err
    if rows and "id" not in rows[0]:
        raise InputError.single(shown, "metadata.csv has no 'id' column")
    ids = [str(row["id"]).strip() for row in rows]
    unsafe = [i for i in ids if not i or Path(i).name != i or i.startswith(".")]
    if unsafe:
        raise InputError.single(shown, f"ids must be plain file stems, got {unsafe[:3]!r}")
    duplicates = sorted({i for i in ids if ids.count(i) > 1})
    missing = [i for i in ids if not (path.parent / f"{i}.png").is_file()]
    problems = [Problem(shown, f"id {i!r} is listed more than once") for i in duplicates]
    problems += [Problem(shown, f"id {i!r} has no PNG ({i}.png not found)") for i in missing]
    if problems:
        raise InputError(problems)
    return ids


def _read_binary_png(path: Path, root: Path) -> NDArray[np.bool_]:
    """A single-channel PNG as a boolean mask (non-zero = inside)."""
    image = read_image(path, root=root)
    if image.ndim != 2:
        reason = f"expected a single-channel binary mask, got {image.shape[2]} channels"
        raise InputError.single(display_path(path, root), reason)
    mask: NDArray[np.bool_] = image > 0
    return mask
