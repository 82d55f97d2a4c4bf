"""Check a capture and its masks together, collecting every problem instead of stopping early.

Used by ``dcseg validate`` and by the HTTP service before it accepts a job. Frames and class
maps are decoded one at a time and only summaries are kept, so memory stays bounded by one
frame; with ``max_pixels`` the total is checked from the image headers before anything is
decoded. Masks are cross-checked against the frame names the capture lists even when some
frames cannot be read, so every problem of every input is reported in one pass.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Iterable, Mapping
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from dcseg.config import CaptureOptions
from dcseg.depthless import depth_summary
from dcseg.errors import InputError, Problem
from dcseg.inputs import RunInputs
from dcseg.io.captures import CaptureListing, list_capture
from dcseg.io.captures.common import iter_frames, select
from dcseg.io.folders import frame_of
from dcseg.io.ground_truth import read_ground_truth
from dcseg.io.images import header_pixels, pixel_budget
from dcseg.io.limits import LimitProblem
from dcseg.io.mask_formats import describe_layout, detect_masks
from dcseg.io.mask_formats.stacks import stack_pixels
from dcseg.io.masks import read_agnostic_masks
from dcseg.io.semantic import iter_semantic_maps, read_vocabulary
from dcseg.types import (
    AgnosticMasks,
    Capture,
    Frame,
    GroundTruth,
    Lens,
    SemanticMap,
    Vocabulary,
)

ASPECT_TOLERANCE = 0.02
"""Largest relative difference between a mask's and its frame's aspect ratio."""

_DECODED_SUFFIXES = (".png", ".npy", ".npz")
"""Files of mask folders that validation decodes (SAM JSON holds RLEs, never decoded)."""

T = TypeVar("T")

FrameSizes = Mapping[str, tuple[int, int] | None]
"""Frame name -> its ``(width, height)``, or None when the frame could not be read."""


@dataclass(frozen=True)
class ValidationReport:
    """The outcome of :func:`validate_inputs`: a summary and every problem found."""

    summary: dict[str, Any]
    problems: tuple[Problem, ...] = field(default_factory=tuple)

    @property
    def ok(self) -> bool:
        return not self.problems


def validate_inputs(
    paths: RunInputs,
    options: CaptureOptions | None = None,
    *,
    max_pixels: int | None = None,
    unlabelled: int | None = None,
) -> ValidationReport:
    """Read every input, cross-check masks against frames, and summarise.

    Args:
        paths: the capture and the optional mask folders, vocabulary and ground truth.
        options: capture reader options (frame stride, size, intrinsics, ...).
        max_pixels: the most pixels all decoded images (colour, depth, masks, class maps) may
            have together; summed from their headers before anything is decoded, and enforced
            on every decode. None = no total limit (each image is still capped).
        unlabelled: a class-map value that means no class (the job option
            ``segment.unlabelled_id``), so it is neither range-checked nor counted as a class.

    Returns:
        A report whose ``problems`` is empty exactly when the inputs are usable together.
        A refusal for ``max_pixels`` is a :class:`~dcseg.io.limits.LimitProblem`.
    """
    options = options or CaptureOptions()
    problems: list[Problem] = []
    summary: dict[str, Any] = {}
    with ExitStack() as stack:
        listed = _attempt(
            problems, lambda: stack.enter_context(list_capture(paths.capture, options))
        )
        if max_pixels is not None:
            over = _over_pixel_budget(paths, listed, options, max_pixels)
            if over is not None:
                return ValidationReport(summary, (*problems, over))
        with pixel_budget(max_pixels):
            frame_sizes = _check_capture(listed, options, problems, summary)
            _check_masks(paths, frame_sizes, problems, summary, unlabelled)
    return ValidationReport(summary, tuple(problems))


def _need(path: Path | None) -> Path:
    assert path is not None
    return path


def _attempt(problems: list[Problem], read: Callable[[], T]) -> T | None:
    """Run a reader; on InputError record its problems and return None."""
    try:
        return read()
    except InputError as error:
        problems.extend(error.problems)
        return None


# --------------------------------------------------------------------------- pixel budget


def _decoded_files(
    paths: RunInputs, listed: CaptureListing | None, options: CaptureOptions
) -> Iterable[Path]:
    """Every file validation will decode as an image or array."""
    if listed is not None:
        for spec in select(listed.listing.specs, options):
            yield spec.rgb
            if spec.depth is not None:
                yield spec.depth
    for folder in (paths.agnostic_masks, paths.semantic_masks):
        if folder is not None and folder.is_dir():
            for path in sorted(folder.rglob("*")):
                if path.suffix.lower() in _DECODED_SUFFIXES and path.is_file():
                    yield path


def _header_pixels(path: Path) -> int | None:
    """Pixels decoding ``path`` gives, from its header (an ``.npz`` mask stack's too)."""
    return stack_pixels(path) if path.suffix.lower() == ".npz" else header_pixels(path)


def _over_pixel_budget(
    paths: RunInputs, listed: CaptureListing | None, options: CaptureOptions, max_pixels: int
) -> Problem | None:
    """The problem of inputs whose headers add up to more than ``max_pixels``, if they do."""
    total = 0
    files = 0
    for path in _decoded_files(paths, listed, options):
        total += _header_pixels(path) or 0
        files += 1
        if total > max_pixels:
            return LimitProblem(
                str(path),
                f"the inputs decode to more than {max_pixels:,} pixels in total (reached at "
                f"this file, number {files:,} of those to decode, from the image headers); "
                "nothing was decoded",
                "max_pixels",
            )
    return None


# --------------------------------------------------------------------------- capture


class _CaptureTally:
    """A capture summary built frame by frame, so frames need not be held together."""

    def __init__(self, layout: str, depthless: dict[str, Any] | None = None) -> None:
        self.layout = layout
        self.depthless = depthless
        self.names: set[str] = set()
        self.sizes: set[str] = set()
        self.frames = 0
        self.pixels = 0
        self.valid = 0
        self.depth_min = float("inf")
        self.depth_max = float("-inf")
        self.lenses: Counter[Lens] = Counter()

    def add(self, frame: Frame) -> list[Problem]:
        """Count ``frame`` in; returns its problems (duplicate name, bad arrays)."""
        out: list[Problem] = []
        if frame.name in self.names:
            out.append(Problem(frame.file("rgb"), f"duplicate frame name {frame.name!r}"))
        self.names.add(frame.name)
        out.extend(frame.problems())
        self.frames += 1
        self.sizes.add(f"{frame.width}x{frame.height}")
        if frame.undistortion is not None:
            self.lenses[frame.undistortion.lens] += 1
        valid = frame.depth[frame.depth > 0]
        self.pixels += int(frame.depth.size)
        self.valid += int(valid.size)
        if valid.size:
            self.depth_min = min(self.depth_min, float(valid.min()))
            self.depth_max = max(self.depth_max, float(valid.max()))
        return out

    def summary(self) -> dict[str, Any]:
        """The same fields as :func:`summarise_capture`."""
        return {
            "layout": self.layout,
            "frames": self.frames,
            "resolution": sorted(self.sizes),
            "depth_min_m": self.depth_min if self.valid else None,
            "depth_max_m": self.depth_max if self.valid else None,
            "depth_valid_fraction": float(self.valid / self.pixels) if self.pixels else 0.0,
            **_lens_summary(self.lenses),
            **(self.depthless or {}),
        }


def _depthless(listed: CaptureListing) -> dict[str, Any] | None:
    """:func:`~dcseg.depthless.depth_summary` of an RGB-only capture, None for one with depth."""
    if listed.listing.depth_source != "none":
        return None
    sparse = listed.listing.sparse
    return depth_summary(None if sparse is None else len(sparse))


def _check_capture(
    listed: CaptureListing | None,
    options: CaptureOptions,
    problems: list[Problem],
    summary: dict[str, Any],
) -> FrameSizes | None:
    """Read the frames one by one; returns the frame sizes masks are checked against (None
    when the capture could not even be listed)."""
    if listed is None:
        return None
    found = list(listed.listing.problems)
    tally = _CaptureTally(listed.layout, _depthless(listed))
    sizes: dict[str, tuple[int, int] | None] = dict.fromkeys(listed.listing.unlisted)
    for spec, frame, frame_problems in iter_frames(listed.listing, listed.folder, options):
        found.extend(frame_problems)
        sizes[spec.name] = None if frame is None else (frame.width, frame.height)
        if frame is not None:
            found.extend(tally.add(frame))
    if not found and not tally.frames:
        found.append(Problem(listed.shown, "capture is empty: no frames found"))
    if not found:
        summary["capture"] = tally.summary()
    problems.extend(found)
    return sizes


# --------------------------------------------------------------------------- masks


def _check_masks(
    paths: RunInputs,
    frame_sizes: FrameSizes | None,
    problems: list[Problem],
    summary: dict[str, Any],
    unlabelled: int | None = None,
) -> None:
    if paths.agnostic_masks is not None:
        agnostic = _attempt(problems, lambda: read_agnostic_masks(_need(paths.agnostic_masks)))
        if agnostic is not None:
            problems += _check_against_frames(agnostic, _agnostic_size, frame_sizes)
            summary["agnostic_masks"] = {
                "format": _format_of(_need(paths.agnostic_masks)),
                **summarise_agnostic(agnostic),
            }
    if paths.semantic_masks is not None or paths.vocabulary is not None:
        vocabulary = _check_semantic(paths, problems, summary, frame_sizes, unlabelled)
    else:
        vocabulary = None
    if paths.ground_truth is not None:
        summary["ground_truth"] = _check_ground_truth(paths.ground_truth, vocabulary, problems)


class _SemanticTally:
    """A class-map summary built map by map."""

    def __init__(self, vocabulary: Vocabulary) -> None:
        self.vocabulary = vocabulary
        self.counts = np.zeros(len(vocabulary), dtype=np.int64)
        self.pixels = 0
        self.frames = 0

    def add(self, semantic: SemanticMap) -> None:
        n = len(self.vocabulary)
        labelled = semantic.classes[semantic.classes >= 0]
        self.counts += np.bincount(labelled.ravel(), minlength=n)[:n]
        self.pixels += int(semantic.classes.size)
        self.frames += 1

    def summary(self) -> dict[str, Any]:
        """The same fields as :func:`summarise_semantic`."""
        return {
            "frames": self.frames,
            "vocabulary_size": len(self.vocabulary),
            "classes_present": [self.vocabulary.names[i] for i in np.flatnonzero(self.counts)],
            "labelled_fraction": float(self.counts.sum() / self.pixels) if self.pixels else 0.0,
        }


def _check_semantic(
    paths: RunInputs,
    problems: list[Problem],
    summary: dict[str, Any],
    frame_sizes: FrameSizes | None,
    unlabelled: int | None = None,
) -> Vocabulary | None:
    if paths.vocabulary is None:
        problems.append(Problem("--vocabulary", "semantic masks need a vocabulary file"))
        return None
    vocabulary = _attempt(problems, lambda: read_vocabulary(_need(paths.vocabulary)))
    if vocabulary is None or paths.semantic_masks is None:
        return vocabulary
    tally = _SemanticTally(vocabulary)
    read_problems: list[Problem] = []
    sizes: dict[str, tuple[tuple[int, int], str]] = {}  # not the maps: one is held at a time
    try:
        for item in iter_semantic_maps(paths.semantic_masks, vocabulary, unlabelled=unlabelled):
            if isinstance(item, Problem):
                read_problems.append(item)
                continue
            tally.add(item)
            sizes[item.name] = _semantic_size(item)
    except InputError as error:  # the folder itself is missing
        read_problems.extend(error.problems)
    problems += _check_against_frames(sizes, lambda size: size, frame_sizes)
    problems += read_problems
    if not read_problems:
        summary["semantic_masks"] = {
            "format": _format_of(paths.semantic_masks),
            **tally.summary(),
        }
    return vocabulary


def _format_of(path: Path) -> str:
    """The mask format detected at ``path``, as ``dcseg validate`` prints it."""
    return describe_layout(detect_masks(path))


def _check_ground_truth(
    path: Path, vocabulary: Vocabulary | None, problems: list[Problem]
) -> dict[str, Any] | None:
    vocabulary = vocabulary or Vocabulary(())  # class-agnostic: the instances are scored
    gt = _attempt(problems, lambda: read_ground_truth(path, len(vocabulary)))
    return None if gt is None else summarise_ground_truth(gt, vocabulary)


def _agnostic_size(masks: AgnosticMasks) -> tuple[tuple[int, int], str]:
    return (masks.width, masks.height), masks.source


def _semantic_size(semantic: SemanticMap) -> tuple[tuple[int, int], str]:
    return (int(semantic.classes.shape[1]), int(semantic.classes.shape[0])), semantic.source


def _check_against_frames(
    per_frame: Mapping[str, T],
    size_of: Callable[[T], tuple[tuple[int, int], str]],
    frame_sizes: FrameSizes | None,
) -> list[Problem]:
    """Masks must belong to listed frames (their stems may add a part name to the frame's:
    :func:`~dcseg.io.folders.frame_of`), one entry each, and have the frame's aspect ratio
    (when the frame could be read)."""
    if frame_sizes is None:
        return []
    out: list[Problem] = []
    claims: dict[str, list[str]] = {}
    for stem, item in sorted(per_frame.items()):
        (width, height), source = size_of(item)
        name = frame_of(stem, frame_sizes) or stem
        claims.setdefault(name, []).append(source or stem)
        if name not in frame_sizes:
            out.append(Problem(source or name, f"mask for frame {name!r}, which the capture lacks"))
            continue
        frame_size = frame_sizes[name]
        if frame_size is None or width == 0 or height == 0:  # unread frame / empty mask list
            continue
        frame_w, frame_h = frame_size
        if abs(width / height - frame_w / frame_h) > ASPECT_TOLERANCE * frame_w / frame_h:
            out.append(
                Problem(
                    source or name,
                    f"mask size {width}x{height} does not match frame size {frame_w}x{frame_h} "
                    "(different aspect ratio, cannot rescale)",
                )
            )
    twice = [(name, found) for name, found in claims.items() if len(found) > 1]
    return out + [
        Problem(f[0], f"frame {n!r} has several masks: " + ", ".join(f)) for n, f in twice
    ]


def summarise_capture(capture: Capture) -> dict[str, Any]:
    """Frame count, resolutions and the valid depth range of a capture."""
    sizes = sorted({f"{f.width}x{f.height}" for f in capture.frames})
    valid = [f.depth[f.depth > 0] for f in capture.frames]
    values = np.concatenate(valid) if valid else np.zeros(0, np.float32)
    pixels = sum(f.depth.size for f in capture.frames)
    return {
        "layout": capture.layout,
        "frames": len(capture),
        "resolution": sizes,
        "depth_min_m": float(values.min()) if values.size else None,
        "depth_max_m": float(values.max()) if values.size else None,
        "depth_valid_fraction": float(values.size / pixels) if pixels else 0.0,
        **_lens_summary(Counter(f.undistortion.lens for f in capture.frames if f.undistortion)),
        **(depth_summary(_points(capture)) if capture.depth_source == "none" else {}),
    }


def _lens_summary(lenses: Mapping[Lens, int]) -> dict[str, list[str]]:
    """``{"undistorted": [...]}``: per lens, how many frames were undistorted through it
    (:mod:`dcseg.lens`); empty when none was."""
    lines = []
    for lens, n in lenses.items():
        shown = " ".join(f"{v:g}" for v in lens.coefficients)
        lines.append(f"{n} frame(s) through the {lens.model} lens ({shown}) of {lens.source}")
    return {"undistorted": lines} if lines else {}


def _points(capture: Capture) -> int | None:
    return None if capture.sparse is None else len(capture.sparse)


def summarise_agnostic(masks: Mapping[str, AgnosticMasks]) -> dict[str, Any]:
    """How many frames have class-agnostic masks, and how many masks per frame."""
    counts = np.array([len(m) for m in masks.values()], dtype=np.int64)
    return {
        "frames": len(masks),
        "masks_per_frame_min": int(counts.min()) if counts.size else 0,
        "masks_per_frame_median": float(np.median(counts)) if counts.size else 0.0,
        "masks_per_frame_max": int(counts.max()) if counts.size else 0,
    }


def summarise_semantic(maps: Mapping[str, SemanticMap], vocabulary: Vocabulary) -> dict[str, Any]:
    """Frames with class maps, the classes that occur and the labelled pixel fraction."""
    counts = np.zeros(len(vocabulary), dtype=np.int64)
    pixels = 0
    for m in maps.values():
        labelled = m.classes[m.classes >= 0]
        counts += np.bincount(labelled.ravel(), minlength=len(vocabulary))[: len(vocabulary)]
        pixels += m.classes.size
    return {
        "frames": len(maps),
        "vocabulary_size": len(vocabulary),
        "classes_present": [vocabulary.names[i] for i in np.flatnonzero(counts)],
        "labelled_fraction": float(counts.sum() / pixels) if pixels else 0.0,
    }


def summarise_ground_truth(gt: GroundTruth, vocabulary: Vocabulary) -> dict[str, Any]:
    """Point count, labelled points and the classes present in the ground truth."""
    labelled = gt.labels[gt.labels >= 0]
    present = np.unique(labelled)
    return {
        "points": int(gt.points.shape[0]),
        "labelled_points": int(labelled.size),
        "classes_present": [vocabulary.names[i] for i in present],
        "instances": None if gt.instances is None else int(np.unique(gt.instances).size),
    }
