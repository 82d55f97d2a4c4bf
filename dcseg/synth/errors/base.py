"""What every segmenter-error generator receives and returns, and the helpers they share.

A generator (:class:`ErrorModel`) is one model of how real 2D segmenters fail. It draws what
it gets wrong about the scene once (:meth:`ErrorModel.prepare`: which objects it confuses,
misses or merges) and then produces each view's class-agnostic masks and class map from the
perfect per-view maps (:meth:`ErrorModel.view`), so its errors repeat across views.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from dcseg.synth.agnostic import min_mask_area
from dcseg.synth.scene import SceneInstance


@dataclass(frozen=True)
class SceneTruth:
    """What a generator may know about the whole scene.

    Attributes:
        instances: the scene's instances by id.
        part_normals: per instance id, a fixed unit normal (for part splits).
        extents: per instance id, its size in metres (diagonal of the 5-95 % box of its
            visible points over all views); instances never seen are absent.
    """

    instances: Mapping[int, SceneInstance]
    part_normals: Mapping[int, NDArray[np.float64]]
    extents: Mapping[int, float]


@dataclass(frozen=True)
class ViewTruth:
    """The perfect maps of one view.

    Attributes:
        instance_map: ``[H, W]`` int32 instance id, -1 = none.
        class_map: ``[H, W]`` int32 ground-truth class index, -1 = none.
        xyz: ``[H, W, 3]`` world point of every pixel.
        depth: ``[H, W]`` float32 noise-free depth, 0 = nothing hit.
    """

    instance_map: NDArray[np.int32]
    class_map: NDArray[np.int32]
    xyz: NDArray[np.float64]
    depth: NDArray[np.float32]


@dataclass(frozen=True)
class ViewOutput:
    """A simulated segmenter's output for one view.

    Attributes:
        masks: ``[M, H, W]`` bool class-agnostic masks, none empty.
        classes: ``[H, W]`` int32 class index, -1 = unlabelled.
        scores: one confidence in [0, 1] per mask, or None when the segmenter gives none.
    """

    masks: NDArray[np.bool_]
    classes: NDArray[np.int32]
    scores: tuple[float, ...] | None = None

    def __post_init__(self) -> None:
        if self.scores is not None and len(self.scores) != len(self.masks):
            raise ValueError(f"{len(self.scores)} scores for {len(self.masks)} masks")


class ErrorModel(Protocol):
    """One independent mechanism of segmenter errors (see :mod:`dcseg.synth.errors`)."""

    name: str

    def prepare(self, scene: SceneTruth, rng: np.random.Generator) -> Any:
        """What the segmenter gets wrong about this scene, drawn once."""

    def view(
        self,
        truth: ViewTruth,
        scene: SceneTruth,
        fates: Any,
        agnostic_rng: np.random.Generator,
        semantic_rng: np.random.Generator,
    ) -> ViewOutput:
        """One view's masks and class map."""


def stack_masks(masks: list[NDArray[np.bool_]], shape: tuple[int, int]) -> NDArray[np.bool_]:
    """``[M, H, W]`` of the masks (an empty ``[0, H, W]`` when there are none)."""
    if not masks:
        return np.zeros((0, *shape), dtype=bool)
    return np.stack(masks)


def keep_large(
    masks: list[NDArray[np.bool_]], scores: list[float] | None = None
) -> tuple[list[NDArray[np.bool_]], list[float] | None]:
    """The masks of at least :func:`~dcseg.synth.agnostic.min_mask_area` pixels (and their
    scores)."""
    if not masks:
        return [], None if scores is None else []
    floor = min_mask_area(*masks[0].shape)
    keep = [i for i, m in enumerate(masks) if int(m.sum()) >= floor]
    kept_scores = None if scores is None else [scores[i] for i in keep]
    return [masks[i] for i in keep], kept_scores


def upsample(small: NDArray[Any], factor: int, shape: tuple[int, int]) -> NDArray[Any]:
    """Repeat the last two axes of ``small`` by ``factor`` and crop or edge-pad to ``shape``."""
    big = np.repeat(np.repeat(small, factor, axis=-2), factor, axis=-1)
    h, w = shape
    big = big[..., :h, :w]
    pad = [(0, 0)] * (big.ndim - 2) + [(0, h - big.shape[-2]), (0, w - big.shape[-1])]
    return np.pad(big, pad, mode="edge")


def dilate(mask: NDArray[np.bool_], radius: int) -> NDArray[np.bool_]:
    """``mask`` grown by a disc of ``radius`` pixels (unchanged for 0)."""
    if radius < 1:
        return mask
    import cv2

    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
    return np.asarray(cv2.dilate(mask.astype(np.uint8), kernel), dtype=bool)


def pair_uniform(salt: int, a: int, b: int) -> float:
    """A uniform number fixed for the unordered pair ``(a, b)`` and the scene's ``salt``: a
    decision about a pair that every view repeats."""
    lo, hi = min(a, b), max(a, b)
    return float(np.random.default_rng([salt, lo, hi]).random())
