"""One COCO instance JSON for all frames (detectors, Grounded-SAM, annotation tools' exports).

The file follows the COCO "object detection" format: ``images`` (``id``, ``file_name``,
``height``, ``width``) and ``annotations`` (``id``, ``image_id``, ``segmentation``, optionally
``category_id``, ``score``, ``iscrowd``). A frame is the stem of its image's ``file_name``.
``segmentation`` is a list of polygons ``[[x1, y1, x2, y2, ...], ...]`` (rasterised with
pycocotools ``frPyObjects``, the reference COCO API) or an RLE, compressed or not. Each
annotation is one class-agnostic mask; images without annotations have no masks. As class maps,
each annotation paints its ``category_id`` (:mod:`dcseg.io.mask_formats.categories`).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pycocotools.mask as mask_util

from dcseg.errors import InputError, Problem
from dcseg.io.folders import FrameSelection
from dcseg.io.images import MAX_PIXELS, display_path, resize_nearest
from dcseg.io.mask_formats import MaskLayout
from dcseg.io.mask_formats.categories import CategoryMap
from dcseg.io.mask_formats.rle import RLE, decode_rle, is_count, to_rle
from dcseg.io.mask_formats.scores import MinScores
from dcseg.types import AgnosticMasks, SemanticMap, Vocabulary

__all__ = ["iter_coco_classes", "read_coco_masks"]


@dataclass(frozen=True)
class _Image:
    stem: str
    height: int
    width: int
    annotations: list[tuple[int, dict[str, Any]]]


def read_coco_masks(
    layout: MaskLayout, frames: FrameSelection | None, min_scores: MinScores
) -> dict[str, AgnosticMasks]:
    """Every (selected) frame's masks at the resolution its ``images`` entry gives, leaving
    out annotations whose ``score`` is below ``min_scores``.

    Raises:
        InputError: listing every problem found (the JSON file, the entry and its field).
    """
    shown, by_stem, problems = _listing(layout, frames, "masks")
    out: dict[str, AgnosticMasks] = {}
    for stem, image in sorted(by_stem.items()):
        rles: list[RLE] = []
        for i, annotation in image.annotations:
            rle, reason = _mask_of(annotation, image)
            keep, bad_score = min_scores.keeps(annotation)
            reason = bad_score or reason
            if rle is None or bad_score:
                problems.append(Problem(shown, f"{_where(i, annotation)}: {reason}"))
            elif keep and mask_util.area(rle) > 0:
                rles.append(rle)
        out[stem] = AgnosticMasks(stem, image.height, image.width, tuple(rles), shown)
    if problems:
        raise InputError(problems)
    return out


def iter_coco_classes(
    layout: MaskLayout,
    vocabulary: Vocabulary,
    size: tuple[int, int] | None,
    frames: FrameSelection | None,
) -> Iterator[SemanticMap | Problem]:
    """Every (selected) frame's class map painted from its annotations' ``category_id``:
    larger masks first, so a smaller object on a larger one keeps its class; pixels no
    annotation covers are unlabelled (-1). A problem in place of a frame that has one."""
    shown, by_stem, problems = _listing(layout, frames, "class maps")
    yield from problems
    categories = CategoryMap.of(layout.data, vocabulary)
    for stem, image in sorted(by_stem.items()):
        painted: list[tuple[int, int, RLE]] = []
        bad: list[Problem] = []
        for i, annotation in image.annotations:
            rle, reason = _mask_of(annotation, image)
            cls, why = _class_of(annotation, categories)
            if rle is None or why:
                bad.append(Problem(shown, f"{_where(i, annotation)}: {reason or why}"))
            else:
                painted.append((int(mask_util.area(rle)), cls, rle))
        if bad:
            yield from bad
            continue
        classes = np.full((image.height, image.width), -1, dtype=np.int32)
        for _, cls, rle in sorted(painted, key=lambda p: -p[0]):
            classes[decode_rle(rle)] = cls
        if size is not None:
            classes = resize_nearest(classes, size)
        yield SemanticMap(stem, classes, shown)


def _listing(
    layout: MaskLayout, frames: FrameSelection | None, what: str
) -> tuple[str, dict[str, _Image], list[Problem]]:
    """The JSON as messages name it, the (selected) images by frame stem with their
    annotations, and the problems of ``images`` and ``annotations``."""
    assert layout.index is not None
    shown = display_path(layout.index, layout.root)
    images, problems = _images(layout.data, shown)
    problems += _attach(layout.data["annotations"], images, shown)
    by_stem = {image.stem: image for image in images.values()}
    if frames is not None:
        by_stem, extra = frames.pick(by_stem, layout.path, what)
        problems += extra
    return shown, by_stem, problems


def _class_of(annotation: dict[str, Any], categories: CategoryMap) -> tuple[int, str]:
    """The vocabulary index of an annotation's ``category_id``, or -1 and why not."""
    category = annotation.get("category_id")
    if not isinstance(category, int) or not is_count(category):
        return -1, f"category_id must be a non-negative integer, got {category!r}"
    return categories.lookup(category)


def _images(data: dict[str, Any], shown: str) -> tuple[dict[int, _Image], list[Problem]]:
    """``images`` by id; problems for missing fields and frames listed twice."""
    raw = data.get("images")
    if not isinstance(raw, list):
        return {}, [Problem(shown, "expected an 'images' list (COCO instance format)")]
    images: dict[int, _Image] = {}
    stems: set[str] = set()
    problems: list[Problem] = []
    for i, entry in enumerate(raw):
        fields = entry if isinstance(entry, dict) else {}
        bad = [
            key
            for key in ("id", "height", "width")
            if not is_count(fields.get(key)) or (key != "id" and fields[key] == 0)
        ]
        name = fields.get("file_name")
        if not isinstance(name, str) or not Path(name).stem:
            bad.append("file_name")
        if bad:
            listed = ", ".join(bad)
            problems.append(Problem(shown, f"images[{i}]: missing or invalid {listed}"))
            continue
        if fields["height"] * fields["width"] > MAX_PIXELS:
            size = f"{fields['width']}x{fields['height']}"
            reason = f"images[{i}]: {size} is above the limit of {MAX_PIXELS:,} pixels"
            problems.append(Problem(shown, reason))
            continue
        stem = Path(str(name)).stem
        if stem in stems or fields["id"] in images:
            problems.append(Problem(shown, f"images[{i}]: frame {stem!r} or id listed twice"))
            continue
        stems.add(stem)
        images[fields["id"]] = _Image(stem, fields["height"], fields["width"], [])
    return images, problems


def _attach(annotations: list[Any], images: dict[int, _Image], shown: str) -> list[Problem]:
    """Give every annotation to its image; a problem for each that names no listed image."""
    problems: list[Problem] = []
    for i, annotation in enumerate(annotations):
        if not isinstance(annotation, dict):
            problems.append(Problem(shown, f"annotations[{i}] must be an object"))
            continue
        ident = annotation.get("image_id", -1)
        image = images.get(ident) if isinstance(ident, int) else None
        if image is None:
            got = annotation.get("image_id")
            reason = f"{_where(i, annotation)}: image_id {got!r} is not in 'images'"
            problems.append(Problem(shown, reason))
        else:
            image.annotations.append((i, annotation))
    return problems


def _where(i: int, annotation: dict[str, Any]) -> str:
    """``annotations[4] (id 17)``: the position, and the id when the annotation has one."""
    ident = annotation.get("id")
    return f"annotations[{i}]" + (f" (id {ident})" if ident is not None else "")


def _mask_of(annotation: dict[str, Any], image: _Image) -> tuple[RLE | None, str]:
    """The annotation's mask as a compressed RLE at the image's size, or None and why."""
    seg = annotation.get("segmentation")
    if isinstance(seg, dict):
        rle, reason = to_rle(seg)
        if rle is None:
            return None, f"segmentation: {reason}"
        if list(rle["size"]) != [image.height, image.width]:
            got = f"{rle['size'][1]}x{rle['size'][0]}"
            return None, f"segmentation RLE is {got}, image is {image.width}x{image.height}"
        return rle, ""
    if not isinstance(seg, list) or not seg:
        return None, "segmentation must be polygons [[x1, y1, ...], ...] or an RLE"
    polygons = [seg] if all(_is_number(v) for v in seg) else seg
    for k, polygon in enumerate(polygons):
        reason = _polygon_problem(polygon) or _outside(polygon, image)
        if reason:
            return None, f"segmentation[{k}] {reason}"
    rles = mask_util.frPyObjects([list(map(float, p)) for p in polygons], image.height, image.width)
    merged = mask_util.merge(rles)
    return {"size": [image.height, image.width], "counts": merged["counts"]}, ""


def _polygon_problem(polygon: Any) -> str:
    """Why ``polygon`` is not a COCO polygon (an even list of >= 6 numbers), or ""."""
    if not isinstance(polygon, list) or not all(_is_number(v) for v in polygon):
        return "must be a list of numbers [x1, y1, x2, y2, ...]"
    if len(polygon) % 2:
        return f"has an odd number of coordinates ({len(polygon)})"
    if len(polygon) < 6:
        return f"has {len(polygon) // 2} points; a polygon needs at least 3"
    if not np.isfinite(np.asarray(polygon, dtype=np.float64)).all():
        return "has a coordinate that is not finite"
    return ""


def _outside(polygon: list[float], image: _Image) -> str:
    """Why a polygon's vertices lie too far outside its image (more than the image's own size
    beyond an edge), or "": pycocotools rasterises edges pixel by pixel in C, and coordinates
    like 1e11 overflow its buffers and crash the process."""
    xy = np.asarray(polygon, dtype=np.float64).reshape(-1, 2)
    limits = np.array([image.width, image.height], dtype=np.float64)
    far = (xy < -limits) | (xy > 2 * limits)
    if not far.any():
        return ""
    point = int(np.flatnonzero(far.any(axis=1))[0])
    x, y = polygon[2 * point], polygon[2 * point + 1]
    return (
        f"point {point + 1} ({x:g}, {y:g}) lies beyond the {image.width}x{image.height} image "
        "by more than its size"
    )


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)
