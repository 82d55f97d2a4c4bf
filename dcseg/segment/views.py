"""Cluster and label maps of every view of a trained scene, one read of each view's weights.

A view in the cache folder (:class:`dcseg.io.run_state.ViewState`) reads its blending weights
from disk on every access, so each function here reads them once per view and renders all it
needs from that read: the cluster map and the class evidence (:func:`cluster_maps`), or the
refined cluster map and the label map (:func:`final_maps`). Both report each view done to
``on_progress(stage, fraction, message)``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from dcseg.progress import Progress
from dcseg.segment.config import MaskConfig
from dcseg.segment.maps import cluster_map

if TYPE_CHECKING:
    from dcseg.io.run_state import ViewState
    from dcseg.segment.evidence import EvidenceSum
    from dcseg.types import SemanticMap


def cluster_maps(
    views: Sequence[ViewState],
    cluster_labels: NDArray[np.int64],
    masks: MaskConfig,
    on_progress: Progress,
    evidence: EvidenceSum | None = None,
    semantic: Mapping[str, SemanticMap] | None = None,
    stage: str = "masks",
) -> dict[str, NDArray[np.int32]]:
    """Every view's cluster map; with ``evidence``, the views that have a class-aware map in
    ``semantic`` also add their class evidence to it in the same pass."""
    maps = {}
    for i, view in enumerate(views):
        blend = view.blend  # read once: a view in the cache folder is loaded per access
        maps[view.name] = cluster_map(blend, cluster_labels, masks)
        if evidence is not None and semantic and view.name in semantic:
            evidence.add(blend, semantic[view.name].classes)
        on_progress(stage, (i + 1) / len(views), f"view {view.name}")
    return maps


def final_maps(
    views: Sequence[ViewState],
    cluster_labels: NDArray[np.int64] | None,
    maps: dict[str, NDArray[np.int32]],
    semantic_ids: NDArray[np.int64],
    masks: MaskConfig,
    filter_label_maps: bool,
    on_progress: Progress,
) -> tuple[dict[str, NDArray[np.int32]], dict[str, NDArray[np.int32]]]:
    """Cluster maps (rendered again when ``cluster_labels`` is given, else ``maps``) and label
    maps rendered from the Gaussians' final classes, in one pass over the views' weights.

    A class is rendered as a cluster is (:func:`dcseg.segment.cluster_map`): per pixel the
    class with the largest blending weight summed over its Gaussians, if at least
    ``masks.min_weight``, then the 2D component filter, which label maps pass only with
    ``filter_label_maps`` (``AssignConfig.filter_label_maps``).
    """
    clusters, classes = {}, {}
    label_masks = masks
    if not filter_label_maps:
        label_masks = replace(masks, min_area_fraction=0.0)
    for i, view in enumerate(views):
        blend = view.blend  # read once: a view in the cache folder is loaded per access
        if cluster_labels is not None:
            clusters[view.name] = cluster_map(blend, cluster_labels, masks)
        classes[view.name] = cluster_map(blend, semantic_ids, label_masks)
        on_progress("refine", (i + 1) / len(views), f"view {view.name}")
    return (clusters if cluster_labels is not None else maps), classes
