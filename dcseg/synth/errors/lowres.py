"""The ``lowres`` generator: a closed-set semantic segmenter and SAM "segment everything".

Mechanism (independent of :mod:`dcseg.synth.failures` and :mod:`.detector`):

* class maps: each instance's class goes through a fixed confusion matrix over similar classes
  (:data:`CONFUSION`), drawn once per instance and kept in **every** view (a deterministic
  network sees the same object the same way); the map is predicted at 1/``factor`` resolution
  as the majority class of each block and upsampled by repetition, so boundaries are blocky
  and objects thinner than a block are swallowed by the stuff around them; every pixel is
  labelled (no abstention);
* agnostic masks at 1/``mask_factor`` resolution: adjacent objects or tables whose median depths
  differ by less than ``merge_depth`` share one mask when their pair was drawn to merge
  (``merge_prob``, once per pair); each object has a low-contrast propensity drawn once
  (Beta with mean ``uncover_mean``) and is left uncovered in a view with that chance; walls and
  the floor are split by texture and shadow into 2-4 pieces with ``stuff_split_prob``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dcseg.synth.errors.base import (
    SceneTruth,
    ViewOutput,
    ViewTruth,
    keep_large,
    pair_uniform,
    stack_masks,
    upsample,
)
from dcseg.synth.failures import REALISTIC_VOCABULARY, fill_unlabelled, touching_pairs
from dcseg.synth.scene import SceneInstance

CONFUSION: Mapping[str, tuple[tuple[str, float], ...]] = {
    "table": (("desk", 0.3), ("shelf", 0.1)),
    "tray": (("plate", 0.3), ("table", 0.1)),
    "duck": (("bird", 0.35), ("teddy", 0.15)),
    "teddy": (("plush toy", 0.4), ("duck", 0.1)),
    "mug": (("cup", 0.45), ("vase", 0.1)),
    "ball": (("globe", 0.3), ("bowl", 0.1)),
    "block": (("brick", 0.3), ("box", 0.1)),
    "lego": (("brick", 0.4), ("block", 0.2)),
    "domino": (("tile", 0.4), ("block", 0.2)),
}
"""Off-diagonal rows of the confusion matrix: per ground-truth class, (predicted class,
probability); the rest of each row is the right class. Walls and floor are never confused."""


@dataclass(frozen=True)
class LowResParams:
    """The segmenters' settings.

    Attributes:
        factor: class maps are predicted at 1/``factor`` resolution.
        mask_factor: agnostic masks are computed at 1/``mask_factor`` resolution.
        merge_depth: adjacent instances closer than this in median depth (m) may merge.
        merge_prob: chance a pair of such instances is merged (drawn once per pair).
        uncover_mean: mean per-object chance of being uncovered in a view.
        uncover_concentration: Beta concentration of that chance (low = some objects almost
            always uncovered, most rarely).
        stuff_split_prob: per view, chance a wall or floor is split into 2-4 masks.
    """

    factor: int = 8
    mask_factor: int = 4
    merge_depth: float = 0.1
    merge_prob: float = 0.6
    uncover_mean: float = 0.2
    uncover_concentration: float = 2.0
    stuff_split_prob: float = 0.5


@dataclass(frozen=True)
class LowResFates:
    """Per instance id its predicted class and uncover chance; a salt for pair decisions."""

    label: dict[int, int] = field(default_factory=dict)
    uncover: dict[int, float] = field(default_factory=dict)
    salt: int = 0


def draw_lowres(scene: SceneTruth, params: LowResParams, rng: np.random.Generator) -> LowResFates:
    """Each instance's row of :data:`CONFUSION` and its uncover chance, drawn once."""
    a = params.uncover_mean * params.uncover_concentration
    b = (1.0 - params.uncover_mean) * params.uncover_concentration
    label, uncover = {}, {}
    for inst_id in sorted(scene.instances):
        inst = scene.instances[inst_id]
        label[inst_id] = REALISTIC_VOCABULARY.index(confused_class(inst.class_name, rng))
        if inst.kind == "object":
            uncover[inst_id] = float(rng.beta(a, b))
    return LowResFates(label, uncover, int(rng.integers(2**31)))


def confused_class(name: str, rng: np.random.Generator) -> str:
    """One draw from the confusion matrix row of ``name``."""
    u = rng.random()
    for other, p in CONFUSION.get(name, ()):
        if u < p:
            return other
        u -= p
    return name


def block_majority(labels: NDArray[np.int32], factor: int) -> NDArray[np.int32]:
    """The most frequent label of each ``factor`` x ``factor`` block (ties: lowest; -1 counts
    as a label), at block resolution; partial blocks at the edges count what they hold."""
    h, w = labels.shape
    hb, wb = -(-h // factor), -(-w // factor)
    shifted = labels.astype(np.int64) + 1
    n = int(shifted.max()) + 1
    rows = (np.arange(h) // factor)[:, None]
    cols = (np.arange(w) // factor)[None, :]
    cell = (rows * wb + cols) * n + shifted
    counts = np.bincount(cell.ravel(), minlength=hb * wb * n).reshape(hb, wb, n)
    winner: NDArray[np.int32] = (counts.argmax(axis=2) - 1).astype(np.int32)
    return winner


def _depth_of(ids: NDArray[np.int32], depth: NDArray[np.float32]) -> dict[int, float]:
    return {int(i): float(np.median(depth[ids == i])) for i in np.unique(ids) if i >= 0}


def _split_stuff(mask: NDArray[np.bool_], rng: np.random.Generator) -> list[NDArray[np.bool_]]:
    """Texture and shadow pieces: 2-4 bands cut at random rows or columns."""
    axis = int(rng.integers(2))
    lines = np.nonzero(mask.any(axis=1 - axis))[0]
    if len(lines) < 4:
        return [mask]
    cuts = np.sort(rng.uniform(lines[0], lines[-1], size=int(rng.integers(1, 4))))
    edges = [lines[0], *cuts.tolist(), lines[-1] + 1]
    index = np.arange(mask.shape[axis])
    out = []
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        band = (index >= lo) & (index < hi)
        out.append(mask & (band[:, None] if axis == 0 else band[None, :]))
    return out


class LowResModel:
    """A low-resolution closed-set segmenter and SAM everything; see the module docstring."""

    name = "lowres"

    def __init__(self, params: LowResParams | None = None) -> None:
        self.params = LowResParams() if params is None else params

    def prepare(self, scene: SceneTruth, rng: np.random.Generator) -> Any:
        return draw_lowres(scene, self.params, rng)

    def view(
        self,
        truth: ViewTruth,
        scene: SceneTruth,
        fates: Any,
        agnostic_rng: np.random.Generator,
        semantic_rng: np.random.Generator,
    ) -> ViewOutput:
        return ViewOutput(self.masks(truth, scene, fates, agnostic_rng), self.classes(truth, fates))

    def classes(self, truth: ViewTruth, fates: LowResFates) -> NDArray[np.int32]:
        """The class map: confused instances, block majority, upsampled, no abstention."""
        ids = truth.instance_map
        predicted = truth.class_map.astype(np.int32, copy=True)
        for inst_id in (int(i) for i in np.unique(ids) if i >= 0):
            predicted[ids == inst_id] = fates.label[inst_id]
        small = block_majority(predicted, self.params.factor)
        return fill_unlabelled(upsample(small, self.params.factor, ids.shape))

    def masks(
        self, truth: ViewTruth, scene: SceneTruth, fates: LowResFates, rng: np.random.Generator
    ) -> NDArray[np.bool_]:
        """SAM everything at mask resolution: merged, uncovered, split stuff; upsampled."""
        f = self.params.mask_factor
        ids = self.segments(truth.instance_map[::f, ::f], truth.depth[::f, ::f], scene, fates, rng)
        masks: list[NDArray[np.bool_]] = []
        for inst_id in (int(i) for i in np.unique(ids) if i >= 0):
            mask = ids == inst_id
            structure = scene.instances[inst_id].kind == "structure"
            if structure and rng.random() < self.params.stuff_split_prob:
                masks.extend(_split_stuff(mask, rng))
            else:
                masks.append(mask)
        shape = (truth.instance_map.shape[0], truth.instance_map.shape[1])
        kept, _ = keep_large([upsample(m, f, shape) for m in masks])
        return stack_masks(kept, shape)

    def segments(
        self,
        ids: NDArray[np.int32],
        depth: NDArray[np.float32],
        scene: SceneTruth,
        fates: LowResFates,
        rng: np.random.Generator,
    ) -> NDArray[np.int32]:
        """The instance map SAM sees: uncovered objects at -1, merged pairs under one id."""
        out = ids.copy()
        for inst_id, chance in sorted(fates.uncover.items()):
            if rng.random() < chance:
                out[ids == inst_id] = -1
        depths = _depth_of(out, depth)
        movable = {i: inst for i, inst in scene.instances.items() if inst.kind != "structure"}
        as_objects = {i: _as_object(inst) for i, inst in movable.items()}
        owner = {i: i for i in depths}  # which segment each instance is in now
        for a, b in touching_pairs(np.where(np.isin(out, list(movable)), out, -1), as_objects):
            keep, gone = owner[a], owner[b]
            close = abs(depths[a] - depths[b]) < self.params.merge_depth
            if keep != gone and close and pair_uniform(fates.salt, a, b) < self.params.merge_prob:
                out[out == gone] = keep
                owner = {i: keep if o == gone else o for i, o in owner.items()}
        return out


def _as_object(inst: SceneInstance) -> SceneInstance:
    """``inst`` seen as an object by :func:`~dcseg.synth.failures.touching_pairs` (tables
    merge with what stands on them too)."""
    return replace(inst, kind="object")
