"""Panoptic segmentations (detectron2, Mask2Former, OneFormer, COCO panoptic): PNG + segments.

A panoptic PNG stores a segment id per pixel as ``id = R + 256 G + 256^2 B`` (panopticapi's
``rgb2id``; a single-channel PNG holds the id itself, a palette PNG its index), 0 = void. Each
id is described by a ``segments_info`` entry with ``id`` and ``category_id`` (``isthing`` is not
needed; a ``score`` filters the agnostic masks like any score). One source feeds both readers:
every segment is a class-agnostic mask, and its category is the class of its pixels.

Categories map to the vocabulary by name when the COCO panoptic JSON lists ``categories``
(``id``, ``name``); otherwise ``category_id`` is the vocabulary index itself (detectron2's
contiguous ids).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dcseg.errors import InputError, Problem
from dcseg.io.folders import FrameSelection
from dcseg.io.images import display_path, read_image, resize_nearest
from dcseg.io.mask_formats import COCO_PANOPTIC, MaskLayout, load_json
from dcseg.io.mask_formats.categories import CategoryMap
from dcseg.io.mask_formats.palette import is_palette_png, read_palette_indices
from dcseg.io.mask_formats.rle import encode
from dcseg.io.mask_formats.scores import MinScores
from dcseg.types import AgnosticMasks, SemanticMap, Vocabulary

__all__ = ["DEVA_FOLDER", "iter_panoptic_classes", "read_panoptic_masks"]


DEVA_FOLDER = "Annotations"
"""Where DEVA writes the id PNGs that its ``pred.json`` describes."""


@dataclass(frozen=True)
class _Frame:
    """One frame's panoptic PNG and the JSON holding its ``segments_info``.

    ``coco``: ``segments`` is the annotation's raw ``segments_info`` (COCO panoptic); else the
    per-frame JSON is parsed only when its frame is read.
    """

    png: Path
    info: Path
    coco: bool = False
    segments: Any = None


def read_panoptic_masks(
    layout: MaskLayout,
    size: tuple[int, int] | None,
    frames: FrameSelection | None,
    min_scores: MinScores | None = None,
) -> dict[str, AgnosticMasks]:
    """Every segment of every (selected) frame as one class-agnostic mask, in
    ``segments_info`` order; segments whose ``score`` (DEVA writes one) is below
    ``min_scores`` are left out.

    Raises:
        InputError: listing every problem found (file, segment and reason).
    """
    listed, problems = _frames(layout, frames)
    out: dict[str, AgnosticMasks] = {}
    for stem, frame in sorted(listed.items()):
        try:
            ids, segments, low = _read_frame(frame, layout.root, size, min_scores or MinScores())
        except InputError as err:
            problems.extend(err.problems)
            continue
        kept = [i for i in segments if i not in low]
        rles = tuple(encode(ids == i) for i in kept if (ids == i).any())
        shown = display_path(frame.png, layout.root)
        out[stem] = AgnosticMasks(stem, int(ids.shape[0]), int(ids.shape[1]), rles, shown)
    if problems:
        raise InputError(problems)
    return out


def iter_panoptic_classes(
    layout: MaskLayout,
    vocabulary: Vocabulary,
    size: tuple[int, int] | None,
    frames: FrameSelection | None,
) -> Iterator[SemanticMap | Problem]:
    """Every (selected) frame's class map, ``-1`` on void pixels; a problem in place of a
    frame that cannot be read."""
    listed, problems = _frames(layout, frames)
    yield from problems
    categories = CategoryMap.of(layout.data, vocabulary)
    for stem, frame in sorted(listed.items()):
        try:
            ids, segments, _ = _read_frame(frame, layout.root, size, MinScores())
            classes = _classes(ids, segments, categories, frame, layout.root)
        except InputError as err:
            yield from err.problems
            continue
        yield SemanticMap(stem, classes, display_path(frame.png, layout.root))


# --------------------------------------------------------------------------- listing


def _frames(
    layout: MaskLayout, frames: FrameSelection | None
) -> tuple[dict[str, _Frame], list[Problem]]:
    """The frames by stem (only the selected ones), and the problems of the listing."""
    if layout.kind == COCO_PANOPTIC:
        listed, problems = _coco_frames(layout)
    else:
        listed, problems = _pair_frames(layout)
    if frames is not None:
        listed, extra = frames.pick(listed, layout.path, "panoptic masks")
        problems.extend(extra)
    return listed, problems


def _coco_frames(layout: MaskLayout) -> tuple[dict[str, _Frame], list[Problem]]:
    """COCO panoptic: ``annotations[i].file_name`` in the folder named after the JSON
    (``panoptic_val2017.json`` + ``panoptic_val2017/``), beside it, or in DEVA's
    ``Annotations/`` (``pred.json`` + ``Annotations/``); a ``.jpg`` name means its ``.png``."""
    assert layout.index is not None
    shown = display_path(layout.index, layout.root)
    here = layout.index.parent
    folders = (here / layout.index.stem, here, here / DEVA_FOLDER)
    listed: dict[str, _Frame] = {}
    problems: list[Problem] = []
    for i, annotation in enumerate(layout.data["annotations"]):
        name = annotation.get("file_name") if isinstance(annotation, dict) else None
        if not isinstance(name, str) or Path(name).name != name or not name:
            reason = f"annotations[{i}].file_name must be a PNG file name, got {name!r}"
            problems.append(Problem(shown, reason))
            continue
        names = (name, f"{Path(name).stem}.png")  # DEVA names the frame's image
        png = next((f / n for n in names for f in folders if (f / n).is_file()), None)
        stem = Path(name).stem
        if png is None:
            where = " or ".join(display_path(f, layout.root) for f in folders)
            problems.append(Problem(shown, f"annotations[{i}]: {name} not found in {where}"))
        elif stem in listed:
            problems.append(Problem(shown, f"annotations[{i}]: frame {stem!r} is listed twice"))
        else:
            listed[stem] = _Frame(png, layout.index, True, annotation.get("segments_info"))
    return listed, problems


def _pair_frames(layout: MaskLayout) -> tuple[dict[str, _Frame], list[Problem]]:
    """Per-frame pairs: ``<stem>.png`` with ``<stem>.json``; either alone is a problem."""
    files = [p for p in sorted(layout.path.iterdir()) if not p.name.startswith(".")]
    pngs = {p.stem: p for p in files if p.suffix.lower() == ".png" and p.is_file()}
    infos = {p.stem: p for p in files if p.suffix.lower() == ".json" and p.is_file()}
    problems = [
        Problem(display_path(pngs[s], layout.root), f"panoptic PNG without its {s}.json")
        for s in sorted(set(pngs) - set(infos))
    ]
    problems += [
        Problem(display_path(infos[s], layout.root), f"segments_info without its {s}.png")
        for s in sorted(set(infos) - set(pngs))
    ]
    return {s: _Frame(pngs[s], infos[s]) for s in sorted(set(pngs) & set(infos))}, problems


# --------------------------------------------------------------------------- one frame


def _read_frame(
    frame: _Frame, root: Path, size: tuple[int, int] | None, min_scores: MinScores
) -> tuple[NDArray[np.int64], dict[int, int], set[int]]:
    """The id map (rescaled to ``size``), ``{segment id: category_id}`` and the ids of the
    segments scoring below ``min_scores``.

    Raises:
        InputError: malformed ``segments_info``, an unreadable PNG, or an id in the PNG that
            ``segments_info`` does not describe.
    """
    raw = frame.segments if frame.coco else load_json(frame.info, root)
    shown_png = display_path(frame.png, root)
    segments, low = _segments(raw, frame, root, min_scores)
    ids = _panoptic_ids(frame.png, root)
    present = np.unique(ids)
    unknown = [int(i) for i in present if i != 0 and int(i) not in segments]
    if unknown:
        described = ", ".join(
            f"{i} (RGB {i % 256},{i // 256 % 256},{i // 65536})" for i in unknown[:5]
        )
        more = f" and {len(unknown) - 5} more" if len(unknown) > 5 else ""
        reason = (
            f"panoptic id {described}{more} not in the segments_info of "
            f"{display_path(frame.info, root)}"
        )
        raise InputError.single(shown_png, reason)
    if size is not None:
        ids = resize_nearest(ids, size)
    return ids, segments, low


def _segments(
    raw: Any, frame: _Frame, root: Path, min_scores: MinScores
) -> tuple[dict[int, int], set[int]]:
    """``{id: category_id}`` from a ``segments_info`` list (or an object holding one), and the
    ids scoring below ``min_scores``."""
    shown = display_path(frame.info, root)
    where = f"segments_info of {frame.png.name}" if frame.coco else "segments_info"
    if isinstance(raw, dict) and not frame.coco:
        raw = raw.get("segments_info")
    if not isinstance(raw, list):
        raise InputError.single(shown, f"{where} must be a list, got {type(raw).__name__}")
    out: dict[int, int] = {}
    low: set[int] = set()
    problems: list[Problem] = []
    for i, segment in enumerate(raw):
        bad = [
            Problem(shown, f"{where}[{i}].{key} must be a non-negative integer, got {value!r}")
            for key in ("id", "category_id")
            if not _is_index(value := segment.get(key) if isinstance(segment, dict) else None)
        ]
        if not bad and segment["id"] in out:
            bad.append(Problem(shown, f"{where}[{i}].id {segment['id']} is repeated"))
        keep, bad_score = min_scores.keeps(segment) if not bad else (True, "")
        if bad_score:
            bad.append(Problem(shown, f"{where}[{i}]: {bad_score}"))
        problems += bad
        if not bad:
            out[segment["id"]] = segment["category_id"]
            if not keep:
                low.add(segment["id"])
    if problems:
        raise InputError(problems)
    return out, low


def _is_index(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0


def _panoptic_ids(path: Path, root: Path) -> NDArray[np.int64]:
    """Segment ids of a panoptic PNG: ``R + 256 G + 256^2 B``, a single-channel id map, or the
    indices of a palette PNG (DEVA's and SAM2's id maps)."""
    if is_palette_png(path):
        return read_palette_indices(path, root=root).astype(np.int64)
    image = read_image(path, root=root)
    if image.ndim == 2:
        return image.astype(np.int64)
    if image.shape[2] != 3:
        channels = image.shape[2]
        reason = f"expected an RGB panoptic PNG (id = R + 256 G + 256^2 B), got {channels} channels"
        raise InputError.single(display_path(path, root), reason)
    rgb = image.astype(np.int64)
    ids: NDArray[np.int64] = rgb[..., 0] + 256 * rgb[..., 1] + 65536 * rgb[..., 2]
    return ids


# --------------------------------------------------------------------------- classes


def _classes(
    ids: NDArray[np.int64],
    segments: dict[int, int],
    categories: CategoryMap,
    frame: _Frame,
    root: Path,
) -> NDArray[np.int32]:
    """The class of every pixel, -1 on void; InputError for a category the vocabulary lacks."""
    values, inverse = np.unique(ids, return_inverse=True)
    lut = np.full(values.size, -1, dtype=np.int32)
    problems: list[Problem] = []
    for k, value in enumerate(values):
        if value == 0:
            continue
        lut[k], reason = categories.lookup(segments[int(value)])
        if reason:
            problems.append(Problem(display_path(frame.info, root), f"segment {value}: {reason}"))
    if problems:
        raise InputError(problems)
    classes: NDArray[np.int32] = lut[inverse.reshape(ids.shape)]
    return classes
