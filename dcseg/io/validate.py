"""Check a capture and its masks together, collecting every problem instead of stopping early.

Used by ``dcseg validate`` and by the HTTP service before it accepts a job.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from dcseg.config import CaptureOptions
from dcseg.errors import InputError, Problem
from dcseg.io.bundle import bundle_paths
from dcseg.io.captures import read_capture
from dcseg.io.ground_truth import read_ground_truth
from dcseg.io.masks import read_agnostic_masks
from dcseg.io.semantic import read_semantic_maps, read_vocabulary
from dcseg.types import AgnosticMasks, Capture, GroundTruth, SemanticMap, Vocabulary

ASPECT_TOLERANCE = 0.02
"""Largest relative difference between a mask's and its frame's aspect ratio."""

T = TypeVar("T")


@dataclass(frozen=True)
class InputPaths:
    """Where the inputs of one job are; only ``capture`` is required."""

    capture: Path
    agnostic_masks: Path | None = None
    semantic_masks: Path | None = None
    vocabulary: Path | None = None
    ground_truth: Path | None = None

    @classmethod
    def in_bundle(cls, root: Path) -> InputPaths:
        """The inputs of a bundle folder (:data:`dcseg.io.bundle.BUNDLE_LAYOUT`)."""
        found = bundle_paths(root)
        return cls(
            capture=root,
            agnostic_masks=found["agnostic_masks"],
            semantic_masks=found["semantic_masks"],
            vocabulary=found["vocabulary"],
            ground_truth=found["ground_truth"],
        )


@dataclass(frozen=True)
class ValidationReport:
    """The outcome of :func:`validate_inputs`: a summary and every problem found."""

    summary: dict[str, Any]
    problems: tuple[Problem, ...] = field(default_factory=tuple)

    @property
    def ok(self) -> bool:
        return not self.problems


def validate_inputs(paths: InputPaths, options: CaptureOptions | None = None) -> ValidationReport:
    """Read every input, cross-check masks against frames, and summarise.

    Args:
        paths: the capture and the optional mask folders, vocabulary and ground truth.
        options: capture reader options (frame stride, size, intrinsics, ...).

    Returns:
        A report whose ``problems`` is empty exactly when the inputs are usable together.
    """
    problems: list[Problem] = []
    summary: dict[str, Any] = {}
    capture = _attempt(problems, lambda: read_capture(paths.capture, options or CaptureOptions()))
    if capture is not None:
        summary["capture"] = summarise_capture(capture)
    frame_sizes = {f.name: (f.width, f.height) for f in capture.frames} if capture else None
    if paths.agnostic_masks is not None:
        agnostic = _attempt(problems, lambda: read_agnostic_masks(_need(paths.agnostic_masks)))
        if agnostic is not None:
            problems += _check_against_frames(agnostic, _agnostic_size, frame_sizes)
            summary["agnostic_masks"] = summarise_agnostic(agnostic)
    if paths.semantic_masks is not None or paths.vocabulary is not None:
        vocabulary = _check_semantic(paths, problems, summary, frame_sizes)
    else:
        vocabulary = None
    if paths.ground_truth is not None:
        summary["ground_truth"] = _check_ground_truth(paths.ground_truth, vocabulary, problems)
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


def _check_semantic(
    paths: InputPaths,
    problems: list[Problem],
    summary: dict[str, Any],
    frame_sizes: Mapping[str, tuple[int, int]] | None,
) -> Vocabulary | None:
    if paths.vocabulary is None:
        problems.append(Problem("--vocabulary", "semantic masks need a vocabulary file"))
        return None
    vocabulary = _attempt(problems, lambda: read_vocabulary(_need(paths.vocabulary)))
    if vocabulary is None or paths.semantic_masks is None:
        return vocabulary
    folder = paths.semantic_masks
    maps = _attempt(problems, lambda: read_semantic_maps(folder, vocabulary))
    if maps is not None:
        problems += _check_against_frames(maps, _semantic_size, frame_sizes)
        summary["semantic_masks"] = summarise_semantic(maps, vocabulary)
    return vocabulary


def _check_ground_truth(
    path: Path, vocabulary: Vocabulary | None, problems: list[Problem]
) -> dict[str, Any] | None:
    if vocabulary is None:
        problems.append(Problem(str(path), "ground truth labels need a vocabulary (--vocabulary)"))
        return None
    gt = _attempt(problems, lambda: read_ground_truth(path, len(vocabulary)))
    return None if gt is None else summarise_ground_truth(gt, vocabulary)


def _agnostic_size(masks: AgnosticMasks) -> tuple[tuple[int, int], str]:
    return (masks.width, masks.height), masks.source


def _semantic_size(semantic: SemanticMap) -> tuple[tuple[int, int], str]:
    return (int(semantic.classes.shape[1]), int(semantic.classes.shape[0])), semantic.source


def _check_against_frames(
    per_frame: Mapping[str, T],
    size_of: Callable[[T], tuple[tuple[int, int], str]],
    frame_sizes: Mapping[str, tuple[int, int]] | None,
) -> list[Problem]:
    """Masks must belong to existing frames and have the frame's aspect ratio."""
    if frame_sizes is None:
        return []
    out: list[Problem] = []
    for name, item in sorted(per_frame.items()):
        (width, height), source = size_of(item)
        if name not in frame_sizes:
            out.append(Problem(source or name, f"mask for frame {name!r}, which the capture lacks"))
            continue
        frame_w, frame_h = frame_sizes[name]
        if width == 0 or height == 0:  # a frame with an empty mask list has no size
            continue
        if abs(width / height - frame_w / frame_h) > ASPECT_TOLERANCE * frame_w / frame_h:
            out.append(
                Problem(
                    source or name,
                    f"mask size {width}x{height} does not match frame size {frame_w}x{frame_h} "
                    "(different aspect ratio, cannot rescale)",
                )
            )
    return out


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
    }


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
