"""Simulated class-aware (open-vocabulary-like) class maps from perfect per-view labels.

Per view: whole instances may take a confusable class (duck <-> teddy, mug -> bowl, ...), rare
classes are often unlabelled or swallowed by the class of what they stand on, classes bleed a
few pixels into their neighbours, and random holes are left unlabelled (-1).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from numpy.typing import NDArray

from dcseg.synth.agnostic import random_ellipses
from dcseg.synth.catalogue import RARE_CLASSES, VOCABULARY
from dcseg.synth.noise import NoiseLevel
from dcseg.synth.scene import SceneInstance

CONFUSIONS = {
    "duck": "teddy",
    "teddy": "duck",
    "mug": "bowl",
    "ball": "bowl",
    "tray": "table",
    "block": "domino",
}
"""The class an instance is mistaken for when the simulated segmenter confuses it."""


def simulate_semantic(
    instance_map: NDArray[np.int32],
    class_map: NDArray[np.int32],
    instances: Mapping[int, SceneInstance],
    level: NoiseLevel,
    rng: np.random.Generator,
) -> NDArray[np.int32]:
    """A noisy per-pixel class map of one view.

    Args:
        instance_map: ``[H, W]`` instance id per pixel, -1 = none.
        class_map: ``[H, W]`` ground-truth vocabulary index, -1 = none.
        instances: the scene's instances by id.
        level: the noise level (``clean`` returns ``class_map`` unchanged).
        rng: seeded generator for this view.

    Returns:
        ``[H, W]`` int32 vocabulary index, -1 = unlabelled.
    """
    out = class_map.astype(np.int32, copy=True)
    for inst_id in (int(i) for i in np.unique(instance_map) if i >= 0):
        relabel = _instance_label(instances[inst_id], instances, level, rng)
        if relabel is not None:
            out[instance_map == inst_id] = relabel
    out = _bleed(out, level, rng)
    if level.hole_rate > 0:
        for hole in random_ellipses(out.shape, int(rng.poisson(level.hole_rate)), 0.08, rng):
            out[hole] = -1
    return out


def _instance_label(
    inst: SceneInstance,
    instances: Mapping[int, SceneInstance],
    level: NoiseLevel,
    rng: np.random.Generator,
) -> int | None:
    """The wrong label a whole instance gets in this view, or None to keep its own."""
    if inst.class_name in RARE_CLASSES:
        if rng.random() >= level.rare_miss_prob:
            return None
        support = instances.get(inst.support)
        if support is None or rng.random() < 0.5:
            return -1
        return VOCABULARY.index(support.class_name)
    target = CONFUSIONS.get(inst.class_name)
    if target is not None and rng.random() < level.confuse_prob:
        return VOCABULARY.index(target)
    return None


def _bleed(
    classes: NDArray[np.int32], level: NoiseLevel, rng: np.random.Generator
) -> NDArray[np.int32]:
    """Let each class, with probability ``bleed_prob``, spread 1..``bleed_px`` pixels outward.

    Classes bleed one after the other (random order) over the current map, so a boundary moves
    one way instead of leaving stripes.
    """
    if level.bleed_px < 1:
        return classes
    import cv2

    out = classes.copy()
    present = [int(c) for c in np.unique(classes) if c >= 0]
    for c in rng.permutation(present).tolist():
        if rng.random() >= level.bleed_prob:
            continue
        radius = int(rng.integers(1, level.bleed_px + 1))
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
        mask = (out == c).astype(np.uint8)
        ring = (cv2.dilate(mask, kernel) > 0) & (mask == 0)
        out[ring] = c
    return out
