"""The ``detector`` generator: an open-set detector whose boxes prompt SAM (Grounded-SAM style).

Mechanism (independent of :mod:`dcseg.synth.failures`):

* per scene, each object or table is detected with a class decided once from its appearance
  and size: with ``confuse_prob`` it takes a class that looks alike
  (:data:`~dcseg.synth.failures.LOOKALIKES`) or has about its size (:data:`NOMINAL_SIZE`),
  and keeps it in ``confuse_view_prob`` of its views; objects smaller than ``small_extent``
  are missed in every view with ``small_miss_prob``; each detection has a base confidence
  (lower for confused and small objects);
* per view, a detection whose confidence (base + noise) falls below ``min_score`` is dropped;
  the others prompt a mask with their box: the box's pixels within ``depth_tol`` of the
  object's median depth, grown from the object (so it bleeds into neighbours at that depth),
  dilated by ``dilate_px`` at 1/``mask_factor`` resolution (coarse, fat boundaries);
* walls and the floor come from the ``wall. floor.`` prompts, coarse but right;
* the class map paints the masks largest first (smaller detections on top, as panoptic
  merges of instance masks do); pixels no mask covers stay unlabelled (detectors abstain).
  Masks carry their confidence as ``score``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dcseg.synth.errors.base import (
    SceneTruth,
    ViewOutput,
    ViewTruth,
    dilate,
    keep_large,
    stack_masks,
    upsample,
)
from dcseg.synth.failures import LOOKALIKES, REALISTIC_VOCABULARY

NOMINAL_SIZE: Mapping[str, float] = {
    "desk": 1.3,
    "shelf": 1.0,
    "plate": 0.3,
    "bird": 0.2,
    "plush toy": 0.4,
    "cup": 0.12,
    "globe": 0.3,
    "brick": 0.1,
    "tile": 0.08,
    "box": 0.3,
    "vase": 0.25,
    "bowl": 0.15,
}
"""Typical size (m) of the vocabulary classes the scene holds no instance of."""
STRUCTURE_SCORE = 0.95
"""Confidence given to the wall and floor masks (painted first, under every detection)."""


@dataclass(frozen=True)
class DetectorParams:
    """The detector's failure rates (per instance unless stated).

    Attributes:
        confuse_prob: chance an object or table is detected as a look-alike or same-size class.
        confuse_view_prob: per view, chance a confused detection shows its wrong class.
        small_extent: objects smaller than this (m) are small.
        small_miss_prob: chance a small object is missed in every view.
        min_score: per view, detections below this confidence are dropped.
        score_noise: standard deviation of a detection's per-view confidence.
        depth_tol: SAM's mask takes the box pixels within this depth (m) of the object.
        box_margin: the box is enlarged by this fraction of its size on each side.
        dilate_px: the mask is dilated by this many pixels at mask resolution.
        mask_factor: masks are computed at 1/``mask_factor`` resolution.
    """

    confuse_prob: float = 0.4
    confuse_view_prob: float = 0.9
    small_extent: float = 0.14
    small_miss_prob: float = 0.6
    min_score: float = 0.35
    score_noise: float = 0.12
    depth_tol: float = 0.12
    box_margin: float = 0.08
    dilate_px: int = 1
    mask_factor: int = 2


@dataclass(frozen=True)
class Detection:
    """What the detector decides once about one instance."""

    label: int
    score: float
    confused: bool = False


@dataclass(frozen=True)
class DetectorFates:
    """Per instance id its detection (missed and structure instances are absent)."""

    detections: dict[int, Detection] = field(default_factory=dict)
    missed: frozenset[int] = frozenset()


def class_sizes(scene: SceneTruth) -> dict[str, float]:
    """Median size per class of the scene's instances, plus :data:`NOMINAL_SIZE`."""
    sizes: dict[str, list[float]] = {}
    for inst_id, extent in scene.extents.items():
        sizes.setdefault(scene.instances[inst_id].class_name, []).append(extent)
    out = dict(NOMINAL_SIZE)
    out.update({name: float(np.median(v)) for name, v in sizes.items()})
    return out


def similar_classes(name: str, extent: float, sizes: Mapping[str, float]) -> list[str]:
    """Classes a detector mistakes ``name`` for: its look-alikes and the two classes (not
    structure) closest to ``extent`` in log-size."""
    near = sorted(
        (abs(np.log(s / max(extent, 1e-3))), other)
        for other, s in sizes.items()
        if other not in (name, "wall", "floor") and s > 0
    )
    return sorted(set(LOOKALIKES.get(name, ())) | {other for _, other in near[:2]})


def draw_detections(
    scene: SceneTruth, params: DetectorParams, rng: np.random.Generator
) -> DetectorFates:
    """Each object's and table's class and confidence, or its miss, drawn once."""
    sizes = class_sizes(scene)
    detections: dict[int, Detection] = {}
    missed: set[int] = set()
    for inst_id in sorted(scene.instances):
        inst = scene.instances[inst_id]
        if inst.kind == "structure" or inst_id not in scene.extents:
            continue
        extent = scene.extents[inst_id]
        small = inst.kind == "object" and extent < params.small_extent
        if small and rng.random() < params.small_miss_prob:
            missed.add(inst_id)
            continue
        score = float(rng.uniform(0.5, 0.95)) - (0.15 if small else 0.0)
        label = REALISTIC_VOCABULARY.index(inst.class_name)
        confused = rng.random() < params.confuse_prob
        if confused:
            choices = similar_classes(inst.class_name, extent, sizes)
            label = REALISTIC_VOCABULARY.index(choices[int(rng.integers(len(choices)))])
            score -= 0.1
        detections[inst_id] = Detection(label, score, confused)
    return DetectorFates(detections, frozenset(missed))


def box_prompted_mask(
    ids: NDArray[np.int32], depth: NDArray[np.float32], inst_id: int, params: DetectorParams
) -> NDArray[np.bool_]:
    """SAM's answer to the box of ``inst_id``: the box pixels at the object's depth, grown from
    the object (it takes neighbours at that depth inside the box), then dilated."""
    from scipy.ndimage import label

    own = ids == inst_id
    rows, cols = np.nonzero(own)
    h, w = ids.shape
    dr = int(np.ceil(params.box_margin * (rows.max() - rows.min() + 1)))
    dc = int(np.ceil(params.box_margin * (cols.max() - cols.min() + 1)))
    box: NDArray[np.bool_] = np.zeros(own.shape, dtype=bool)
    box[max(0, rows.min() - dr) : min(h, rows.max() + dr + 1),
        max(0, cols.min() - dc) : min(w, cols.max() + dc + 1)] = True  # fmt: skip
    median = float(np.median(depth[own]))
    near = box & (depth > 0) & (np.abs(depth - median) < params.depth_tol)
    parts, _ = label(near | own)
    touched = np.unique(parts[own])
    grown: NDArray[np.bool_] = np.isin(parts, touched[touched > 0])
    return dilate(grown, params.dilate_px) & box


class DetectorModel:
    """Detector boxes prompting SAM; see the module docstring."""

    name = "detector"

    def __init__(self, params: DetectorParams | None = None) -> None:
        self.params = DetectorParams() if params is None else params

    def prepare(self, scene: SceneTruth, rng: np.random.Generator) -> Any:
        return draw_detections(scene, self.params, rng)

    def view(
        self,
        truth: ViewTruth,
        scene: SceneTruth,
        fates: Any,
        agnostic_rng: np.random.Generator,
        semantic_rng: np.random.Generator,
    ) -> ViewOutput:
        f = self.params.mask_factor
        ids, depth = truth.instance_map[::f, ::f], truth.depth[::f, ::f]
        visible = [int(i) for i in np.unique(ids) if i >= 0]
        masks, labels, scores = self._structure(ids, visible, scene)
        n_structure = len(masks)
        for inst_id in visible:
            found = fates.detections.get(inst_id)
            if found is None:
                continue
            score = found.score + float(agnostic_rng.normal(0.0, self.params.score_noise))
            if score < self.params.min_score:
                continue
            label = found.label
            if found.confused and semantic_rng.random() >= self.params.confuse_view_prob:
                label = REALISTIC_VOCABULARY.index(scene.instances[inst_id].class_name)
            masks.append(box_prompted_mask(ids, depth, inst_id, self.params))
            labels.append(label)
            scores.append(float(np.clip(score, 0.0, 1.0)))
        return self._output(masks, labels, scores, n_structure, (f, *truth.instance_map.shape))

    def _structure(
        self, ids: NDArray[np.int32], visible: list[int], scene: SceneTruth
    ) -> tuple[list[NDArray[np.bool_]], list[int], list[float]]:
        """Wall and floor masks from their prompts: right, at mask resolution."""
        masks, labels, scores = [], [], []
        for inst_id in visible:
            inst = scene.instances[inst_id]
            if inst.kind == "structure":
                masks.append(ids == inst_id)
                labels.append(REALISTIC_VOCABULARY.index(inst.class_name))
                scores.append(STRUCTURE_SCORE)
        return masks, labels, scores

    @staticmethod
    def _output(
        masks: list[NDArray[np.bool_]],
        labels: list[int],
        scores: list[float],
        n_structure: int,
        factor_shape: tuple[int, int, int],
    ) -> ViewOutput:
        """Upsample, paint the class map (walls and floor first, then the detections largest
        first), drop tiny masks."""
        factor, h, w = factor_shape
        big = [upsample(m, factor, (h, w)) for m in masks]
        classes = np.full((h, w), -1, dtype=np.int32)
        areas = [-int(m.sum()) for m in masks[n_structure:]]
        detections = np.argsort(areas, kind="stable") + n_structure
        for i in [*range(n_structure), *detections.tolist()]:
            classes[big[i]] = labels[i]
        kept, kept_scores = keep_large(big, scores)
        return ViewOutput(stack_masks(kept, (h, w)), classes, tuple(kept_scores or ()))
