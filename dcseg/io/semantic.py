"""Class-aware 2D segmentations (open-vocabulary segmenter output) and vocabularies <-> files.

A semantic-map folder holds one single-channel class map per frame, matched by file stem:

* ``<stem>.png`` uint8 (255 = unlabelled) or uint16 (65535 = unlabelled); a palette PNG (VOC,
  DEVA) is read by palette index, 255 = unlabelled;
* ``<stem>.npy`` integer (negative = unlabelled).

One more value may be declared unlabelled (``unlabelled``, the job option
``segment.unlabelled_id``): ScanNet's ``label-filt`` PNGs use 0 for unannotated pixels, which
then vote for no class instead of the vocabulary's first.

The folder may instead be a panoptic source (:mod:`dcseg.io.mask_formats.panoptic`): each
segment's category is the class of its pixels; or one COCO instance JSON, whose annotations
paint their categories (:mod:`dcseg.io.mask_formats.coco`).

Values index into a :class:`~dcseg.types.Vocabulary`, read from ``.txt`` (one class name per
line) or ``.json`` (a list of strings). In memory maps are int32 with ``-1`` = unlabelled.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable, Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dcseg.errors import InputError, Problem
from dcseg.io.folders import FrameSelection, entries_by_stem
from dcseg.io.images import display_path, read_image, resize_nearest, write_image
from dcseg.io.mask_formats import (
    COCO_INSTANCES,
    COCO_PANOPTIC,
    PANOPTIC_PAIRS,
    MaskLayout,
    detect_masks,
)
from dcseg.io.mask_formats.coco import iter_coco_classes
from dcseg.io.mask_formats.palette import is_palette_png, read_palette_indices
from dcseg.io.mask_formats.panoptic import iter_panoptic_classes
from dcseg.io.npy import read_npy_map
from dcseg.types import SemanticMap, Vocabulary

__all__ = [
    "iter_semantic_maps",
    "read_semantic_maps",
    "without_class",
    "read_vocabulary",
    "write_semantic_png",
    "write_vocabulary",
]

logger = logging.getLogger(__name__)

MAP_SUFFIXES = (".png", ".npy")
UNLABELLED_PNG = {np.dtype(np.uint8): 255, np.dtype(np.uint16): 65535}
MAX_REPORTED_VALUES = 5
_PLURAL = {"line": "lines", "entry": "entries"}

_LayoutReader = Callable[
    [MaskLayout, Vocabulary, tuple[int, int] | None, FrameSelection | None],
    Iterator[SemanticMap | Problem],
]
_LAYOUT_READERS: dict[str, _LayoutReader] = {
    COCO_INSTANCES: iter_coco_classes,
    COCO_PANOPTIC: iter_panoptic_classes,
    PANOPTIC_PAIRS: iter_panoptic_classes,
}
"""Class-map readers of the layouts that are not one file per frame."""


# --------------------------------------------------------------------------- vocabulary


def read_vocabulary(path: Path) -> Vocabulary:
    """Read class names from ``.txt`` (one per line, blank lines skipped) or ``.json`` (a list).

    Raises:
        InputError: the file is missing or unreadable, has another extension, is empty, holds
            non-string or blank entries, or names a class twice.
    """
    shown = path.name
    suffix = path.suffix.lower()
    if suffix not in (".txt", ".json"):
        reason = f"unsupported vocabulary format {suffix!r}: use .txt or .json"
        raise InputError.single(shown, reason)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as err:
        raise InputError.single(shown, f"cannot read vocabulary: {err}") from err
    entries = _txt_entries(text) if suffix == ".txt" else _json_entries(text, shown)
    problems = _vocabulary_problems(entries, shown, "line" if suffix == ".txt" else "entry")
    if problems:
        raise InputError(problems)
    return Vocabulary(tuple(name for _, name in entries), str(path))


def write_vocabulary(path: Path, vocab: Vocabulary) -> None:
    """Write class names as ``.txt`` (one per line) or ``.json`` (a list), by extension."""
    suffix = path.suffix.lower()
    if suffix == ".txt":
        bad = [n for n in vocab.names if "\n" in n or "\r" in n or n != n.strip() or not n]
        if bad:
            raise ValueError(f"class names {bad!r} cannot be written one per line; use .json")
        text = "".join(f"{name}\n" for name in vocab.names)
    elif suffix == ".json":
        text = json.dumps(list(vocab.names), indent=1, ensure_ascii=False) + "\n"
    else:
        raise ValueError(f"unsupported vocabulary format {suffix!r}: use .txt or .json")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text, encoding="utf-8")


def _txt_entries(text: str) -> list[tuple[int, Any]]:
    """(1-based line number, stripped name) of every non-blank line."""
    lines = enumerate(text.splitlines(), start=1)
    return [(number, line.strip()) for number, line in lines if line.strip()]


def _json_entries(text: str, shown: str) -> list[tuple[int, Any]]:
    """(1-based position, entry) of every element of a JSON list."""
    try:
        data = json.loads(text)
    except json.JSONDecodeError as err:
        reason = f"malformed JSON at line {err.lineno}, column {err.colno}: {err.msg}"
        raise InputError.single(shown, reason) from err
    if not isinstance(data, list):
        reason = f"expected a JSON list of class names, got {type(data).__name__}"
        raise InputError.single(shown, reason)
    return list(enumerate(data, start=1))


def _vocabulary_problems(entries: list[tuple[int, Any]], shown: str, unit: str) -> list[Problem]:
    """Empty vocabulary, non-string or blank entries, and duplicate names."""
    if not entries:
        return [Problem(shown, "vocabulary is empty: no class names found")]
    problems: list[Problem] = []
    seen: dict[str, list[int]] = {}
    for place, name in entries:
        if not isinstance(name, str):
            kind = type(name).__name__
            reason = f"{unit} {place}: class name must be a string, got {kind} {name!r}"
            problems.append(Problem(shown, reason))
        elif not name.strip():
            problems.append(Problem(shown, f"{unit} {place}: class name is blank"))
        else:
            seen.setdefault(name, []).append(place)
    for name, places in seen.items():
        if len(places) > 1:
            where = ", ".join(str(p) for p in places)
            problems.append(
                Problem(shown, f"class {name!r} appears more than once ({_PLURAL[unit]} {where})")
            )
    return problems


# --------------------------------------------------------------------------- semantic maps


def read_semantic_maps(
    folder: Path,
    vocabulary: Vocabulary,
    *,
    size: tuple[int, int] | None = None,
    frames: FrameSelection | None = None,
    unlabelled: int | None = None,
) -> dict[str, SemanticMap]:
    """Read every frame's class map from a folder of ``.png`` / ``.npy`` files.

    Args:
        folder: the folder of class maps, one per frame stem.
        vocabulary: the classes the maps index into; indices must be ``< len(vocabulary)``.
        size: optional target ``(width, height)``; maps are rescaled with nearest neighbour.
        frames: read only these frames' maps (a run's keyframes); None = every file.
        unlabelled: a value that marks unlabelled pixels besides the format's own (255 /
            65535 in PNGs, negative in ``.npy``); for panoptic and COCO sources, the class
            index it gives. None = only the format's own.

    Returns:
        Maps keyed by frame stem (sorted), ``[H, W]`` int32 with ``-1`` = unlabelled.

    Raises:
        InputError: listing every problem found (file and reason).
    """
    out: dict[str, SemanticMap] = {}
    problems: list[Problem] = []
    items = iter_semantic_maps(folder, vocabulary, size=size, frames=frames, unlabelled=unlabelled)
    for item in items:
        if isinstance(item, Problem):
            problems.append(item)
        else:
            out[item.name] = item
    if problems:
        raise InputError(problems)
    return out


def iter_semantic_maps(
    folder: Path,
    vocabulary: Vocabulary,
    *,
    size: tuple[int, int] | None = None,
    frames: FrameSelection | None = None,
    unlabelled: int | None = None,
) -> Iterator[SemanticMap | Problem]:
    """Like :func:`read_semantic_maps`, one map at a time (for checks that must not hold them
    all); each problem is yielded in place of the map it concerns.

    Raises:
        InputError: the folder does not exist.
    """
    if not folder.is_dir() and not folder.is_file():
        raise InputError.single(str(folder), "semantic map folder not found (or not a folder)")
    layout = detect_masks(folder)
    whole = _LAYOUT_READERS.get(layout.kind)
    if whole is not None:
        for item in whole(layout, vocabulary, size, frames):
            yield item if isinstance(item, Problem) else without_class(item, unlabelled)
        return
    entries, problems = _map_entries(folder)
    if frames is not None:
        entries, extra = frames.pick(entries, folder, "class maps")
        problems.extend(extra)
    yield from problems
    for stem, path in sorted(entries.items()):
        try:
            classes = _read_class_map(path, folder.parent, len(vocabulary), unlabelled)
        except InputError as err:
            yield from err.problems
            continue
        if size is not None:
            classes = resize_nearest(classes, size)
        yield SemanticMap(stem, classes, display_path(path, folder.parent))


def write_semantic_png(path: Path, m: SemanticMap, n_classes: int) -> None:
    """Write a class map as a single-channel PNG readable by :func:`read_semantic_maps`.

    The PNG is uint8 with 255 = unlabelled when ``n_classes < 255``, else uint16 with
    65535 = unlabelled.

    Args:
        path: destination ``.png`` file; parent folders are created.
        m: the class map.
        n_classes: the vocabulary size.

    Raises:
        ValueError: ``path`` is not a ``.png``, ``n_classes`` does not fit in uint16, or the
            map has indices outside ``[-1, n_classes)``.
    """
    if path.suffix.lower() != ".png":
        raise ValueError(f"semantic maps are written as .png, got {path.name}")
    if not 0 < n_classes < 65535:
        raise ValueError(f"n_classes must be in [1, 65535), got {n_classes}")
    classes = m.classes
    if classes.size and (int(classes.min()) < -1 or int(classes.max()) >= n_classes):
        raise ValueError(
            f"{m.name}: class indices must be in [-1, {n_classes}), "
            f"got [{int(classes.min())}, {int(classes.max())}]"
        )
    dtype = np.uint8 if n_classes < 255 else np.uint16
    image: NDArray[np.unsignedinteger[Any]] = np.where(
        classes < 0, UNLABELLED_PNG[np.dtype(dtype)], classes
    ).astype(dtype)
    write_image(path, image)


def _map_entries(folder: Path) -> tuple[dict[str, Path], list[Problem]]:
    """Map stems to class-map files; report stems that appear in more than one format."""

    def stem_of(entry: Path) -> str | None:
        return None if entry.is_dir() or entry.suffix.lower() not in MAP_SUFFIXES else entry.stem

    return entries_by_stem(folder, stem_of, "class maps")


def without_class(m: SemanticMap, unlabelled: int | None) -> SemanticMap:
    """``m`` with the class ``unlabelled`` (if any) made unlabelled (-1)."""
    if unlabelled is None:
        return m
    classes = m.classes.copy()
    classes[classes == unlabelled] = -1
    return replace(m, classes=classes)


def _read_class_map(
    path: Path, root: Path, n_classes: int, extra: int | None = None
) -> NDArray[np.int32]:
    """One class map as int32 with -1 = unlabelled (the format's own value, and ``extra``),
    checked against the vocabulary size."""
    shown = display_path(path, root)
    if path.suffix.lower() == ".png":
        raw = _read_png_map(path, root, shown)
        unlabelled = raw == UNLABELLED_PNG[raw.dtype]
    else:
        raw = _read_npy_map(path, shown)
        unlabelled = raw < 0
    if extra is not None:
        unlabelled |= raw == extra
    _check_range(raw[~unlabelled], n_classes, shown)
    classes = raw.astype(np.int32)
    classes[unlabelled] = -1
    return classes


def _read_png_map(path: Path, root: Path, shown: str) -> NDArray[Any]:
    if is_palette_png(path):
        return read_palette_indices(path, root=root)
    image = read_image(path, root=root)
    if image.ndim != 2:
        reason = f"expected a single-channel class map, got {image.shape[2]} channels"
        raise InputError.single(shown, reason)
    if image.dtype not in UNLABELLED_PNG:
        raise InputError.single(shown, f"expected a uint8 or uint16 class map, got {image.dtype}")
    return image


def _read_npy_map(path: Path, shown: str) -> NDArray[Any]:
    array = read_npy_map(path, shown)
    if array.dtype.kind not in "iu":
        raise InputError.single(shown, f"expected an integer class map, got {array.dtype}")
    if array.ndim != 2:
        reason = f"expected a 2D class map [H, W], got shape {tuple(array.shape)}"
        raise InputError.single(shown, reason)
    return array


def _check_range(labelled: NDArray[Any], n_classes: int, shown: str) -> None:
    """Raise naming every out-of-range class value (up to a few) and its pixel count."""
    bad = labelled[labelled >= n_classes]
    if not bad.size:
        return
    values, counts = np.unique(bad, return_counts=True)
    listed = ", ".join(
        f"{int(v)} ({int(c)} pixel{'s' if c != 1 else ''})"
        for v, c in zip(values[:MAX_REPORTED_VALUES], counts[:MAX_REPORTED_VALUES], strict=True)
    )
    extra = len(values) - MAX_REPORTED_VALUES
    more = f" and {extra} more value(s)" if extra > 0 else ""
    reason = f"class index out of range for a vocabulary of {n_classes} classes: {listed}{more}"
    raise InputError.single(shown, reason)
