"""Simulated class-agnostic (SAM-like) masks from perfect per-view instance maps.

Per view, each visible instance yields its mask; depending on the noise level, objects also
yield two part masks (split by a plane in 3D, so the split is roughly consistent across views),
supports yield a group mask with the objects on them, walls and the floor are over-split,
boundaries are dilated or eroded, masks go missing, and spurious blobs appear. Masks overlap
(whole, parts and groups together) as SAM's multi-granularity output does.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from dcseg.synth.noise import NoiseLevel
from dcseg.synth.scene import SceneInstance


def min_mask_area(height: int, width: int) -> int:
    """Smallest mask kept, in pixels (tiny fragments are dropped as SAM does)."""
    return max(4, height * width // 2000)


def simulate_agnostic(
    instance_map: NDArray[np.int32],
    xyz: NDArray[np.float64],
    instances: Mapping[int, SceneInstance],
    part_normals: Mapping[int, NDArray[np.float64]],
    level: NoiseLevel,
    rng: np.random.Generator,
) -> NDArray[np.bool_]:
    """Class-agnostic masks of one view.

    Args:
        instance_map: ``[H, W]`` instance id per pixel, -1 = none.
        xyz: ``[H, W, 3]`` world point of every pixel (used for 3D part splits).
        instances: the scene's instances by id.
        part_normals: per instance id, the unit normal of its part-splitting plane.
        level: the noise level.
        rng: seeded generator for this view.

    Returns:
        ``[M, H, W]`` boolean masks in random order, each at least :func:`min_mask_area` pixels.
    """
    visible = [int(i) for i in np.unique(instance_map) if i >= 0]
    masks: list[NDArray[np.bool_]] = []
    for inst_id in visible:
        mask = instance_map == inst_id
        inst = instances[inst_id]
        if inst.kind == "structure" and rng.random() < level.wall_split_prob:
            masks.extend(_split_columns(mask, rng))
        else:
            masks.append(mask)
        if inst.kind != "structure" and rng.random() < level.part_prob:
            masks.extend(_split_plane(mask, xyz, part_normals[inst_id], rng))
    masks.extend(_groups(instance_map, visible, instances, level, rng))
    masks = [_jitter(m, level, rng) for m in masks]
    masks = [m for m in masks if rng.random() >= level.miss_prob]
    masks.extend(_spurious(instance_map.shape, level.spurious_rate, rng))
    floor = min_mask_area(*instance_map.shape)
    kept = [m for m in masks if int(m.sum()) >= floor]
    if not kept:
        return np.zeros((0, *instance_map.shape), dtype=bool)
    order = rng.permutation(len(kept))
    return np.stack([kept[int(i)] for i in order])


def _split_columns(mask: NDArray[np.bool_], rng: np.random.Generator) -> list[NDArray[np.bool_]]:
    """Cut a mask into 2-4 pieces at random image columns."""
    cols = np.nonzero(mask.any(axis=0))[0]
    if len(cols) < 4:
        return [mask]
    cuts = np.sort(rng.uniform(cols[0], cols[-1], size=int(rng.integers(1, 4))))
    edges = [cols[0], *cuts.tolist(), cols[-1] + 1]
    column = np.arange(mask.shape[1])
    pieces = []
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        pieces.append(mask & ((column >= lo) & (column < hi))[None, :])
    return pieces


def _split_plane(
    mask: NDArray[np.bool_],
    xyz: NDArray[np.float64],
    normal: NDArray[np.float64],
    rng: np.random.Generator,
) -> list[NDArray[np.bool_]]:
    """Two parts of a mask on either side of a plane through its 3D points (offset jittered)."""
    side = np.zeros(mask.shape, dtype=np.float64)
    side[mask] = xyz[mask] @ normal
    values = side[mask]
    cut = float(np.median(values)) + rng.normal(0.0, 0.15) * float(values.std())
    below = mask & (side < cut)
    return [below, mask & ~below]


def _descendants(root: int, instances: Mapping[int, SceneInstance]) -> set[int]:
    """Ids of everything standing on ``root``, directly or indirectly."""
    out: set[int] = set()
    frontier = [root]
    while frontier:
        parent = frontier.pop()
        children = [i for i, inst in instances.items() if inst.support == parent]
        out.update(children)
        frontier.extend(children)
    return out


def _groups(
    instance_map: NDArray[np.int32],
    visible: Sequence[int],
    instances: Mapping[int, SceneInstance],
    level: NoiseLevel,
    rng: np.random.Generator,
) -> list[NDArray[np.bool_]]:
    """Masks uniting a table or tray with the visible objects standing on it."""
    out: list[NDArray[np.bool_]] = []
    for inst_id in visible:
        if instances[inst_id].kind == "structure":
            continue
        members = _descendants(inst_id, instances) & set(visible)
        if members and rng.random() < level.group_prob:
            out.append(np.isin(instance_map, [inst_id, *sorted(members)]))
    return out


def _jitter(
    mask: NDArray[np.bool_], level: NoiseLevel, rng: np.random.Generator
) -> NDArray[np.bool_]:
    """Dilate or erode a mask by 1..``jitter_px`` pixels with probability ``jitter_prob``."""
    if level.jitter_px < 1 or rng.random() >= level.jitter_prob:
        return mask
    import cv2

    radius = int(rng.integers(1, level.jitter_px + 1))
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
    image = mask.astype(np.uint8)
    moved = cv2.dilate(image, kernel) if rng.random() < 0.5 else cv2.erode(image, kernel)
    return np.asarray(moved, dtype=bool)


def random_ellipses(
    shape: tuple[int, ...], count: int, scale: float, rng: np.random.Generator
) -> list[NDArray[np.bool_]]:
    """``count`` filled ellipses with semi-axes up to ``scale`` of the image size."""
    import cv2

    h, w = int(shape[0]), int(shape[1])
    out: list[NDArray[np.bool_]] = []
    for _ in range(count):
        canvas = np.zeros((h, w), dtype=np.uint8)
        centre = (int(rng.integers(0, w)), int(rng.integers(0, h)))
        axes = (
            max(1, int(w * rng.uniform(0.3, 1.0) * scale)),
            max(1, int(h * rng.uniform(0.3, 1.0) * scale)),
        )
        cv2.ellipse(canvas, centre, axes, float(rng.uniform(0, 180)), 0, 360, 1, -1)
        out.append(canvas.astype(bool))
    return out


def _spurious(
    shape: tuple[int, ...], rate: float, rng: np.random.Generator
) -> list[NDArray[np.bool_]]:
    """Spurious blobs (Poisson count with mean ``rate``)."""
    if rate <= 0:
        return []
    return random_ellipses(shape, int(rng.poisson(rate)), 0.12, rng)
