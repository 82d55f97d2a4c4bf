"""Failures of real 2D segmenters, for the ``realistic`` noise level of ``dcseg synth``.

The other levels draw every error independently per view, which multi-view fusion averages
away. Real segmenters fail consistently (``../shared/docs/evaluation.md``):

* open-vocabulary class maps: an instance mistaken for a look-alike class is mistaken in most
  views; rare objects are missed in every view; small objects take the class of their support;
  maps are predicted at 1/4 resolution and upsampled (blocky boundaries); every pixel gets a
  class (no abstention); the vocabulary is larger than the scene, with look-alike names;
* SAM-style masks: computed at a lower resolution, touching objects merged into one mask,
  10-30 % of the objects uncovered in a view, three nested levels (part, object, group).

What is decided once per scene (an instance's look-alike, a rare object's miss) is an
:class:`InstanceFates` drawn from its own random stream; the rest is drawn per view.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dcseg.synth.agnostic import simulate_agnostic
from dcseg.synth.catalogue import RARE_CLASSES, VOCABULARY
from dcseg.synth.noise import Failures, NoiseLevel
from dcseg.synth.scene import SceneInstance

LOOKALIKES: Mapping[str, tuple[str, ...]] = {
    "table": ("desk",),
    "tray": ("plate", "table"),
    "duck": ("bird", "teddy"),
    "teddy": ("plush toy", "duck"),
    "mug": ("cup", "bowl"),
    "ball": ("globe", "bowl"),
    "block": ("brick", "domino"),
    "lego": ("brick", "block"),
    "domino": ("tile", "block"),
}
"""Per ground-truth class, the classes an open-vocabulary segmenter mistakes it for."""

EXTRA_CLASSES: tuple[str, ...] = ("desk", "plate", "bird", "plush toy", "cup", "globe", "brick")
EXTRA_CLASSES += ("tile", "rug", "shelf", "box", "vase")
"""Classes the realistic vocabulary adds after :data:`~dcseg.synth.catalogue.VOCABULARY`
(never in the ground truth): look-alike names and objects the scene does not hold."""

REALISTIC_VOCABULARY: tuple[str, ...] = VOCABULARY + EXTRA_CLASSES
"""The realistic level's vocabulary: the scene's classes keep their indices."""


@dataclass(frozen=True)
class InstanceFates:
    """What a scene's segmenter gets wrong consistently, drawn once per scene.

    Attributes:
        lookalike: instance id -> vocabulary index of the class it is mistaken for.
        missed: ids of rare objects missed in every view.
    """

    lookalike: dict[int, int] = field(default_factory=dict)
    missed: frozenset[int] = frozenset()


def draw_fates(
    instances: Mapping[int, SceneInstance], failures: Failures, rng: np.random.Generator
) -> InstanceFates:
    """Which instances get a look-alike class and which rare objects are missed."""
    lookalike: dict[int, int] = {}
    missed: set[int] = set()
    for inst_id in sorted(instances):
        inst = instances[inst_id]
        if inst.class_name in RARE_CLASSES and rng.random() < failures.rare_miss_prob:
            missed.add(inst_id)
            continue
        choices = LOOKALIKES.get(inst.class_name, ())
        if choices and rng.random() < failures.lookalike_prob:
            name = choices[int(rng.integers(len(choices)))]
            lookalike[inst_id] = REALISTIC_VOCABULARY.index(name)
    return InstanceFates(lookalike, frozenset(missed))


def _support_class(inst: SceneInstance, instances: Mapping[int, SceneInstance]) -> int:
    support = instances.get(inst.support)
    return -1 if support is None else REALISTIC_VOCABULARY.index(support.class_name)


def realistic_classes(
    instance_map: NDArray[np.int32],
    class_map: NDArray[np.int32],
    instances: Mapping[int, SceneInstance],
    fates: InstanceFates,
    failures: Failures,
    rng: np.random.Generator,
) -> NDArray[np.int32]:
    """One view's class map before the per-view noise: fates, swallowed small objects.

    Args:
        instance_map: ``[H, W]`` instance id per pixel, -1 = none.
        class_map: ``[H, W]`` ground-truth class per pixel, -1 = none.
        instances: the scene's instances by id.
        fates: the scene's consistent failures.
        failures: the level's parameters.
        rng: this view's generator.

    Returns:
        ``[H, W]`` int32 class per pixel (-1 where the ground truth has none).
    """
    out = class_map.astype(np.int32, copy=True)
    small = failures.swallow_fraction * instance_map.size
    ids, areas = np.unique(instance_map[instance_map >= 0], return_counts=True)
    for inst_id, area in zip(ids.tolist(), areas.tolist(), strict=True):
        inst = instances[inst_id]
        pixels = instance_map == inst_id
        if inst_id in fates.missed or (inst.kind == "object" and area < small):
            out[pixels] = _support_class(inst, instances)
        elif inst_id in fates.lookalike and rng.random() < failures.lookalike_view_prob:
            out[pixels] = fates.lookalike[inst_id]
    return out


def coarse(labels: NDArray[Any], factor: int) -> NDArray[Any]:
    """``labels`` predicted at 1/``factor`` resolution and upsampled by repetition: each
    ``factor`` x ``factor`` block takes the label at its centre (blocky boundaries)."""
    if factor == 1:
        return labels.copy()
    h, w = labels.shape[:2]
    small = labels[factor // 2 :: factor, factor // 2 :: factor]
    big = np.repeat(np.repeat(small, factor, axis=0), factor, axis=1)
    pad = ((0, max(0, h - big.shape[0])), (0, max(0, w - big.shape[1])))
    return np.pad(big, pad, mode="edge")[:h, :w]


def fill_unlabelled(classes: NDArray[np.int32]) -> NDArray[np.int32]:
    """Every pixel takes a class: pixels at -1 take their nearest labelled pixel's class."""
    from scipy.ndimage import distance_transform_edt

    missing = classes < 0
    if not missing.any() or missing.all():
        return classes.copy()
    _, (rows, cols) = distance_transform_edt(missing, return_indices=True)
    filled: NDArray[np.int32] = classes[rows, cols].astype(np.int32)
    return filled


def touching_pairs(
    instance_map: NDArray[np.int32], instances: Mapping[int, SceneInstance]
) -> list[tuple[int, int]]:
    """Pairs of objects (not structure or furniture) whose pixels touch (4-neighbours)."""
    pairs: set[tuple[int, int]] = set()
    for a, b in (
        (instance_map[1:], instance_map[:-1]),
        (instance_map[:, 1:], instance_map[:, :-1]),
    ):
        edge = (a != b) & (a >= 0) & (b >= 0)
        for x, y in zip(a[edge].tolist(), b[edge].tolist(), strict=True):
            if instances[x].kind == "object" and instances[y].kind == "object":
                pairs.add((min(x, y), max(x, y)))
    return sorted(pairs)


def sam_instance_map(
    instance_map: NDArray[np.int32],
    instances: Mapping[int, SceneInstance],
    failures: Failures,
    rng: np.random.Generator,
) -> NDArray[np.int32]:
    """The objects a SAM-style segmenter sees in a view: some uncovered, touching ones merged.

    Returns a copy of ``instance_map`` where a drawn 10-30 % (``failures.uncovered``) of the
    visible objects are -1 and each merged pair of touching objects carries the lower id.
    """
    out = instance_map.copy()
    visible = [int(i) for i in np.unique(instance_map) if i >= 0]
    objects = [i for i in visible if instances[i].kind == "object"]
    share = rng.uniform(*failures.uncovered)
    hidden = rng.permutation(objects)[: round(share * len(objects))].tolist()
    for inst_id in hidden:
        out[instance_map == inst_id] = -1
    for a, b in touching_pairs(out, instances):
        if rng.random() < failures.merge_prob:
            out[out == b] = a
    return out


def realistic_agnostic(
    instance_map: NDArray[np.int32],
    xyz: NDArray[np.float64],
    instances: Mapping[int, SceneInstance],
    part_normals: Mapping[int, NDArray[np.float64]],
    level: NoiseLevel,
    failures: Failures,
    rng: np.random.Generator,
) -> NDArray[np.bool_]:
    """SAM-style masks of one view: :func:`simulate_agnostic` on the segmenter's view of the
    objects (:func:`sam_instance_map`) at 1/``failures.mask_factor`` resolution, upsampled.

    ``level`` is the :class:`~dcseg.synth.noise.NoiseLevel`; its part and group chances give
    the nested levels (part, object, group).
    """
    seen = sam_instance_map(instance_map, instances, failures, rng)
    f = failures.mask_factor
    small = simulate_agnostic(seen[::f, ::f], xyz[::f, ::f], instances, part_normals, level, rng)
    h, w = instance_map.shape
    big = np.repeat(np.repeat(small, f, axis=1), f, axis=2)[:, :h, :w]
    pad = ((0, 0), (0, h - big.shape[1]), (0, w - big.shape[2]))
    return np.pad(big, pad, mode="edge")


def realistic_semantic(
    instance_map: NDArray[np.int32],
    class_map: NDArray[np.int32],
    instances: Mapping[int, SceneInstance],
    fates: InstanceFates,
    level: NoiseLevel,
    failures: Failures,
    rng: np.random.Generator,
) -> NDArray[np.int32]:
    """An open-vocabulary class map of one view: the scene's consistent failures
    (:func:`realistic_classes`), then the level's per-view noise
    (:func:`~dcseg.synth.semantic.simulate_semantic`), predicted at 1/``class_factor``
    resolution (:func:`coarse`) and, with ``never_abstain``, with every pixel labelled."""
    from dcseg.synth.semantic import simulate_semantic

    classes = realistic_classes(instance_map, class_map, instances, fates, failures, rng)
    classes = simulate_semantic(instance_map, classes, instances, level, rng)
    classes = coarse(classes, failures.class_factor)
    return fill_unlabelled(classes) if failures.never_abstain else classes
