"""Dense 2D label maps: IoU between two of them, and connected-component filtering.

Label maps are ``[H, W]`` integer arrays with -1 = no label. Everything here is O(H x W) in
memory (never one binary mask per label).
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import find_objects


def check_label_map(label_map: NDArray[Any], n_labels: int, what: str) -> NDArray[np.int64]:
    """``label_map`` as int64 after checking it is 2D with values in ``[-1, n_labels)``."""
    array = np.asarray(label_map)
    if array.ndim != 2 or not np.issubdtype(array.dtype, np.integer):
        raise ValueError(f"{what} must be an [H, W] integer map, got {array.shape} {array.dtype}")
    if array.size and (array.min() < -1 or array.max() >= n_labels):
        raise ValueError(
            f"{what} values must be in [-1, {n_labels}), got [{array.min()}, {array.max()}]"
        )
    return array.astype(np.int64, copy=False)


def mask_iou(
    cluster_ids: NDArray[Any], class_map: NDArray[Any], n_clusters: int, n_classes: int
) -> NDArray[np.float64]:
    """IoU of every cluster mask with every class mask, from one joint histogram.

    Args:
        cluster_ids: ``[H, W]`` int cluster id per pixel, -1 = no cluster.
        class_map: ``[H, W]`` int class index per pixel, -1 = no class.
        n_clusters: K; ids must be < K.
        n_classes: C; indices must be < C.

    Returns:
        ``[K, C]`` float64 IoU = |cluster ∩ class| / |cluster ∪ class|; 0 where the union is
        empty.
    """
    a = check_label_map(cluster_ids, n_clusters, "cluster_ids").ravel()
    b = check_label_map(class_map, n_classes, "class_map").ravel()
    if a.shape != b.shape:
        raise ValueError(f"map sizes differ: {cluster_ids.shape} vs {class_map.shape}")
    both = (a >= 0) & (b >= 0)
    inter = np.bincount(a[both] * n_classes + b[both], minlength=n_clusters * n_classes)
    inter = inter.reshape(n_clusters, n_classes).astype(np.float64)
    area_a = np.bincount(a[a >= 0], minlength=n_clusters).astype(np.float64)
    area_b = np.bincount(b[b >= 0], minlength=n_classes).astype(np.float64)
    union = area_a[:, None] + area_b[None, :] - inter
    return np.divide(inter, union, out=np.zeros_like(inter), where=union > 0)


def label_components(
    label_map: NDArray[np.int64],
) -> Iterator[tuple[int, tuple[slice, ...], NDArray[np.bool_], NDArray[np.int32], NDArray[Any]]]:
    """8-connected components of each label's mask, one label at a time, in label order.

    Each label is processed inside its bounding box only (found for all labels in one pass).

    Yields:
        ``(label, box, mask, components, areas)``: the bounding-box slices, the label's mask
        in the box, cv2's component image in the box (0 = background) and the area in pixels
        of every component (index 0 = background).
    """
    if label_map.size == 0:
        return
    for index, box in enumerate(find_objects(label_map + 1)):
        if box is None:
            continue
        mask = label_map[box] == index
        _, comps, stats, _ = cv2.connectedComponentsWithStats(
            mask.astype(np.uint8), connectivity=8, ltype=cv2.CV_32S
        )
        yield index, box, mask, comps, stats[:, cv2.CC_STAT_AREA]


def clean_cluster_map(cluster_ids: NDArray[Any], min_area: int) -> NDArray[np.int64]:
    """The 2D connected-component filter (method doc §4): drop small pieces of cluster masks.

    Args:
        cluster_ids: ``[H, W]`` int cluster id per pixel, -1 = none.
        min_area: pieces (8-connected components of one cluster's mask) with fewer pixels
            than this are set to -1; 0 keeps everything.

    Returns:
        ``[H, W]`` int64 cleaned copy.
    """
    ids = check_label_map(cluster_ids, np.iinfo(np.int64).max, "cluster_ids")
    out = ids.copy()
    if min_area <= 0:
        return out
    for _, box, mask, comps, areas in label_components(ids):
        small = areas < min_area
        small[0] = False
        out[box][mask & small[comps]] = -1
    return out


def component_counts(class_map: NDArray[Any], n_classes: int, min_area: int) -> NDArray[np.int64]:
    """Per class, the number of its mask's 8-connected components with >= ``min_area`` pixels.

    A class present only in smaller pieces counts 1; an absent class counts 0.

    Args:
        class_map: ``[H, W]`` int class index per pixel, -1 = none.
        n_classes: C.
        min_area: smallest component that counts.

    Returns:
        ``[C]`` int64 counts.
    """
    classes = check_label_map(class_map, n_classes, "class_map")
    counts = np.zeros(n_classes, dtype=np.int64)
    for index, _, _, _, areas in label_components(classes):
        counts[index] = max(1, int(np.count_nonzero(areas[1:] >= min_area)))
    return counts
