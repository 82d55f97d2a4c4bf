"""Class-agnostic 2D masks (SAM-style: overlapping, multi-granularity) <-> files.

A mask folder holds one entry per frame, matched to the capture by file stem. Each entry is one of:

* ``<stem>.json``: SAM ``amg.py --convert-to-rle`` output, a JSON list of records whose
  ``segmentation`` is a COCO RLE (compressed string counts, or uncompressed list counts); or
  Grounded-SAM-2's object with such records (and their ``score``) under ``annotations``.
* ``<stem>/``: SAM ``amg.py`` folder output, binary PNGs ``<id>.png`` (0/255) listed by the
  ``id`` column of ``metadata.csv``.
* ``<stem>.png``: an integer label map (uint8/uint16), 0 = no mask, every other value = one mask;
  a palette PNG (DAVIS, SAM2, DEVA, VOC) is read by palette index, 0 and 255 (VOC's void) = none.
* ``<stem>.npy``: an integer label map, negative = no mask, every other value = one mask.
* ``<stem>.npy`` / ``<stem>.npz``: an ``[M, H, W]`` stack of binary masks, the ``.npz`` with
  optional per-mask scores (:mod:`dcseg.io.mask_formats.stacks`).

The whole folder (or the JSON file given) may instead be one COCO instance JSON for all frames
(polygons or RLE; :mod:`dcseg.io.mask_formats.coco`) or one panoptic source (COCO panoptic JSON
+ PNGs, or per-frame PNG + ``segments_info`` JSON pairs; :mod:`dcseg.io.mask_formats.panoptic`):
every annotation or segment is a mask.

Masks are kept compact as COCO RLEs (``{"size": [H, W], "counts": bytes}``) and are only
decoded on demand, one frame (or one mask) at a time. Empty masks are dropped.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pycocotools.mask as mask_util
from numpy.typing import NDArray

from dcseg.errors import InputError, Problem
from dcseg.io.folders import FrameSelection, entries_by_stem
from dcseg.io.images import display_path, read_image, resize_nearest
from dcseg.io.mask_formats import (
    COCO_INSTANCES,
    COCO_PANOPTIC,
    PANOPTIC_PAIRS,
    MaskLayout,
    detect_masks,
)
from dcseg.io.mask_formats.coco import read_coco_masks
from dcseg.io.mask_formats.palette import PALETTE_VOID, is_palette_png, read_palette_indices
from dcseg.io.mask_formats.panoptic import read_panoptic_masks
from dcseg.io.mask_formats.rle import RLE, encode
from dcseg.io.mask_formats.rle import decode_rle as _decode_rle
from dcseg.io.mask_formats.rle import to_rle as _to_rle
from dcseg.io.mask_formats.sam_folder import read_png_folder
from dcseg.io.mask_formats.scores import MinScores
from dcseg.io.mask_formats.stacks import is_stack, read_stack
from dcseg.io.npy import read_npy_map
from dcseg.types import AgnosticMasks

__all__ = [
    "decode_masks",
    "mask_areas",
    "masks_from_dense",
    "masks_from_label_map",
    "read_agnostic_masks",
    "resize_masks",
    "write_agnostic_json",
]

logger = logging.getLogger(__name__)

_encode = encode
"""Kept under its old name: :mod:`dcseg.warmup` encodes its masks with it."""

MASK_SUFFIXES = (".json", ".png", ".npy", ".npz")


# --------------------------------------------------------------------------- public helpers


def masks_from_dense(name: str, dense: NDArray[np.bool_], source: str = "") -> AgnosticMasks:
    """Encode a dense stack as compact RLE masks, dropping empty ones.

    Args:
        name: the frame stem.
        dense: ``[M, H, W]`` boolean masks.
        source: the file the masks came from.

    Returns:
        The non-empty masks, in input order.
    """
    if dense.ndim != 3:
        raise ValueError(f"dense masks must be [M, H, W], got shape {dense.shape}")
    _, height, width = dense.shape
    rles = [_encode(dense[i]) for i in range(dense.shape[0]) if dense[i].any()]
    _log_dropped(name, dense.shape[0] - len(rles))
    return AgnosticMasks(name, int(height), int(width), tuple(rles), source)


def masks_from_label_map(
    name: str,
    labels: NDArray[np.integer[Any]],
    *,
    none_below: int = 0,
    void: int | None = None,
    source: str = "",
) -> AgnosticMasks:
    """Turn an integer label map into one mask per distinct value ``>= none_below``.

    Args:
        name: the frame stem.
        labels: ``[H, W]`` integer label map.
        none_below: values below this mean "no mask" (0 for ``.npy`` maps where negative = none,
            1 for PNG maps where 0 = none).
        void: a value that is no mask either (a palette PNG's 255, VOC's boundaries).
        source: the file the map came from.

    Returns:
        Masks ordered by increasing label value.
    """
    if labels.ndim != 2:
        raise ValueError(f"label map must be [H, W], got shape {labels.shape}")
    values = np.unique(labels)
    rles = tuple(_encode(labels == v) for v in values if v >= none_below and v != void)
    return AgnosticMasks(name, int(labels.shape[0]), int(labels.shape[1]), rles, source)


def decode_masks(m: AgnosticMasks, index: Sequence[int] | None = None) -> NDArray[np.bool_]:
    """Decode masks into a dense boolean stack (for one frame at a time).

    Args:
        m: the masks.
        index: positions of the masks to decode, in the wanted order; None = all.

    Returns:
        ``[M, H, W]`` bool, ``M = len(index)`` (or ``len(m)``).
    """
    rles = list(m.rles) if index is None else [m.rles[i] for i in index]
    stack = np.zeros((len(rles), m.height, m.width), dtype=np.bool_)
    for i, rle in enumerate(rles):
        stack[i] = _decode_rle(rle)
    return stack


def mask_areas(m: AgnosticMasks) -> NDArray[np.int64]:
    """The pixel count of every mask.

    Args:
        m: the masks.

    Returns:
        ``[M]`` int64 areas.
    """
    if not m.rles:
        return np.zeros(0, dtype=np.int64)
    return np.asarray(mask_util.area(list(m.rles)), dtype=np.int64)


def resize_masks(m: AgnosticMasks, size: tuple[int, int]) -> AgnosticMasks:
    """Resample masks with nearest neighbour, decoding one mask at a time to bound memory.

    Uses the pixel-centre rule of :func:`dcseg.io.images.resize_nearest`. Masks that vanish at
    the new resolution are dropped.

    Args:
        m: the masks.
        size: target ``(width, height)``.

    Returns:
        The resampled masks (``m`` itself when already at that size).
    """
    width, height = size
    if width < 1 or height < 1:
        raise ValueError(f"size must be positive, got {size}")
    if (m.width, m.height) == (width, height):
        return m
    return map_masks(m, lambda mask: resize_nearest(mask, size), size)


def map_masks(
    m: AgnosticMasks,
    resample: Callable[[NDArray[np.bool_]], NDArray[np.bool_]],
    size: tuple[int, int],
) -> AgnosticMasks:
    """Every mask through ``resample`` (a dense ``[H, W]`` bool map to one of ``size``,
    ``(width, height)``), decoding one mask at a time to bound memory; masks left with no pixel
    are dropped."""
    rles = []
    for rle in m.rles:
        mapped = resample(_decode_rle(rle))
        if mapped.any():
            rles.append(_encode(mapped))
    _log_dropped(m.name, len(m.rles) - len(rles))
    width, height = size
    return AgnosticMasks(m.name, height, width, tuple(rles), m.source)


def write_agnostic_json(path: Path, masks: AgnosticMasks) -> None:
    """Write masks as a SAM ``amg.py --convert-to-rle`` JSON file.

    Each record has ``segmentation`` (COCO RLE, string counts), ``area``, ``bbox`` (XYWH) and
    ``crop_box`` (the full image). SAM's ``predicted_iou``, ``stability_score`` and
    ``point_coords`` are not known here and are left out. Parent folders are created.

    Args:
        path: the destination ``.json`` file.
        masks: the masks to write.
    """
    areas = mask_areas(masks)
    boxes = mask_util.toBbox(list(masks.rles)) if masks.rles else np.zeros((0, 4))
    records = [
        {
            "segmentation": {"size": list(rle["size"]), "counts": rle["counts"].decode("ascii")},
            "area": int(area),
            "bbox": [int(round(float(v))) for v in box],
            "crop_box": [0, 0, masks.width, masks.height],
        }
        for rle, area, box in zip(masks.rles, areas, boxes, strict=True)
    ]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(records), encoding="utf-8")


# --------------------------------------------------------------------------- folder reader

_LayoutReader = Callable[
    [MaskLayout, tuple[int, int] | None, FrameSelection | None, MinScores],
    dict[str, AgnosticMasks],
]


def _read_coco(
    layout: MaskLayout,
    size: tuple[int, int] | None,
    frames: FrameSelection | None,
    min_scores: MinScores,
) -> dict[str, AgnosticMasks]:
    masks = read_coco_masks(layout, frames, min_scores)
    return masks if size is None else {k: resize_masks(m, size) for k, m in masks.items()}


_LAYOUT_READERS: dict[str, _LayoutReader] = {
    COCO_INSTANCES: _read_coco,
    COCO_PANOPTIC: read_panoptic_masks,
    PANOPTIC_PAIRS: read_panoptic_masks,
}
"""Readers of the layouts that are not one entry per frame."""


def read_agnostic_masks(
    folder: Path,
    *,
    size: tuple[int, int] | None = None,
    frames: FrameSelection | None = None,
    min_scores: MinScores | None = None,
) -> dict[str, AgnosticMasks]:
    """Read every frame's class-agnostic masks from a folder (formats: see the module docstring),
    in the format :func:`~dcseg.io.mask_formats.detect_masks` finds there.

    Args:
        folder: the mask folder (or a COCO JSON file).
        size: optional target ``(width, height)``; masks are rescaled with nearest neighbour.
        frames: read only these frames' masks (a run's keyframes); None = every entry.
        min_scores: drop masks scoring below these (where the format gives scores: SAM and
            Grounded-SAM JSON, COCO, panoptic segments, ``.npz``); None = keep all.

    Returns:
        Masks keyed by frame stem, in sorted stem order. An empty SAM JSON list gives no masks
        of size ``size`` (or 0x0 when ``size`` is None). Hidden entries and files with other
        extensions are ignored.

    Raises:
        InputError: listing every problem found (file and reason).
    """
    layout = detect_masks(folder)
    min_scores = min_scores or MinScores()
    whole = _LAYOUT_READERS.get(layout.kind)
    if whole is not None:
        return whole(layout, size, frames, min_scores)
    entries, problems = _mask_entries(folder)
    if frames is not None:
        entries, extra = frames.pick(entries, folder, "masks")
        problems.extend(extra)
    out: dict[str, AgnosticMasks] = {}
    for stem, entry in sorted(entries.items()):
        try:
            out[stem] = _read_entry(entry, stem, folder.parent, size, min_scores)
        except InputError as err:
            problems.extend(err.problems)
    if problems:
        raise InputError(problems)
    return out


def _mask_entries(folder: Path) -> tuple[dict[str, Path], list[Problem]]:
    """Map stems to mask entries (files or PNG folders); report stems in several formats."""

    def stem_of(entry: Path) -> str | None:
        if entry.is_dir():
            return entry.name
        return entry.stem if entry.suffix.lower() in MASK_SUFFIXES else None

    return entries_by_stem(folder, stem_of, "masks")


def _read_entry(
    entry: Path, stem: str, root: Path, size: tuple[int, int] | None, min_scores: MinScores
) -> AgnosticMasks:
    """Read one frame's masks in whichever format ``entry`` has, rescaled to ``size``.

    Files are named relative to ``root`` in messages and in ``AgnosticMasks.source``.
    """
    shown = display_path(entry, root)
    if entry.is_dir():
        masks = read_png_folder(entry, stem, root)
    elif entry.suffix.lower() == ".json":
        masks = _read_json(entry, stem, shown, size, min_scores)
    elif entry.suffix.lower() in (".npz", ".npy") and is_stack(entry):
        masks = read_stack(entry, stem, root, min_scores)
    else:
        labels, none_below, void = _read_label_map(entry, root)
        if size is not None:
            labels = resize_nearest(labels, size)
        masks = masks_from_label_map(stem, labels, none_below=none_below, void=void, source=shown)
    return masks if size is None else resize_masks(masks, size)


# --------------------------------------------------------------------------- SAM JSON


def _read_json(
    path: Path, stem: str, shown: str, size: tuple[int, int] | None, min_scores: MinScores
) -> AgnosticMasks:
    """Read a SAM amg.py JSON file of RLE records."""
    try:
        records = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as err:
        reason = f"malformed JSON at line {err.lineno}, column {err.colno}: {err.msg}"
        raise InputError.single(shown, reason) from err
    except (OSError, UnicodeDecodeError) as err:
        raise InputError.single(shown, f"cannot read file: {err}") from err
    if isinstance(records, dict) and isinstance(records.get("annotations"), list):
        records = records["annotations"]  # Grounded-SAM-2: one object per image
    if not isinstance(records, list):
        reason = f"expected a JSON list of SAM mask records, got {type(records).__name__}"
        raise InputError.single(shown, reason)
    rles, problems = _records_to_rles(records, shown, min_scores)
    if problems:
        raise InputError(problems)
    if not rles:
        width, height = size if size is not None else (0, 0)
        logger.debug("%s: no mask records", shown)
        return AgnosticMasks(stem, height, width, (), shown)
    height, width = (int(v) for v in rles[0]["size"])
    kept = tuple(r for r in rles if mask_util.area(r) > 0)
    _log_dropped(stem, len(rles) - len(kept))
    return AgnosticMasks(stem, height, width, kept, shown)


def _records_to_rles(
    records: list[Any], shown: str, min_scores: MinScores
) -> tuple[list[RLE], list[Problem]]:
    """Convert every record's segmentation to a compressed RLE, leaving out records scoring
    below ``min_scores``; collect every problem."""
    rles: list[RLE] = []
    problems: list[Problem] = []
    for i, record in enumerate(records):
        seg = record.get("segmentation") if isinstance(record, dict) else None
        if seg is None:
            problems.append(Problem(shown, f"record {i} has no 'segmentation'"))
            continue
        rle, reason = _to_rle(seg)
        keep, bad_score = min_scores.keeps(record)
        if bad_score:
            problems.append(Problem(shown, f"record {i}: {bad_score}"))
        elif rle is None:
            problems.append(Problem(shown, f"record {i}: {reason}"))
        elif rles and rle["size"] != rles[0]["size"]:
            problems.append(Problem(shown, _size_mismatch(i, rle["size"], rles[0]["size"])))
        elif keep:
            rles.append(rle)
    return rles, problems


def _size_mismatch(i: int, got: list[int], first: list[int]) -> str:
    return (
        f"record {i}: RLE size {got[1]}x{got[0]} (WxH) disagrees with {first[1]}x{first[0]} "
        "of the other records"
    )


# --------------------------------------------------------------------------- label maps


def _read_label_map(path: Path, root: Path) -> tuple[NDArray[np.integer[Any]], int, int | None]:
    """An integer label map, the value below which pixels have no mask, and a void value."""
    shown = display_path(path, root)
    if path.suffix.lower() == ".png" and is_palette_png(path):
        return read_palette_indices(path, root=root), 1, PALETTE_VOID
    if path.suffix.lower() == ".png":
        image = read_image(path, root=root)
        if image.ndim != 2 or image.dtype not in (np.uint8, np.uint16):
            raise InputError.single(shown, _label_png_reason(image))
        return image, 1, None
    labels = read_npy_map(path, shown)
    if labels.ndim != 2 or labels.dtype.kind not in "iu":
        reason = f"expected a 2D integer label map, got {labels.ndim}D {labels.dtype}"
        raise InputError.single(shown, reason)
    return labels, 0, None


def _label_png_reason(image: NDArray[Any]) -> str:
    if image.ndim != 2:
        return f"expected a single-channel label map, got {image.shape[2]} channels"
    return f"expected a uint8 or uint16 label map, got {image.dtype}"


# --------------------------------------------------------------------------- small helpers


def _log_dropped(name: str, n_dropped: int) -> None:
    if n_dropped:
        logger.debug("%s: dropped %d empty mask(s)", name, n_dropped)
