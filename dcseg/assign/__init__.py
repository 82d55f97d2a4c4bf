"""Stage: label clusters with classes from class-aware 2D maps (method doc §6, Part B.7).

Entry point: :func:`assign_labels`. Masks arrive as dense ``[H, W]`` int label maps (-1 = none):
cluster-id maps rendered from the clustering, class maps from ``SemanticMap.classes``.

The exports are resolved lazily (PEP 562): ``import dcseg.assign.config`` (which the CLI and
the service import for every command) does not import scipy.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from dcseg._lazy import lazy_exports
from dcseg.assign.config import AssignConfig
from dcseg.assign.vote import decide, tally, vote  # eager: `vote` also names the submodule

if TYPE_CHECKING:
    from dcseg.assign.consistency import inconsistent
    from dcseg.assign.masks import clean_cluster_map, component_counts, mask_iou
    from dcseg.assign.matching import Match, class_replicas, match_view
    from dcseg.assign.stage import Assignment, assign_labels, view_matches

__all__ = [
    "AssignConfig",
    "Assignment",
    "Match",
    "assign_labels",
    "class_replicas",
    "clean_cluster_map",
    "component_counts",
    "decide",
    "inconsistent",
    "mask_iou",
    "match_view",
    "tally",
    "view_matches",
    "vote",
]

_HOME = {
    "Assignment": "dcseg.assign.stage",
    "Match": "dcseg.assign.matching",
    "assign_labels": "dcseg.assign.stage",
    "class_replicas": "dcseg.assign.matching",
    "clean_cluster_map": "dcseg.assign.masks",
    "component_counts": "dcseg.assign.masks",
    "inconsistent": "dcseg.assign.consistency",
    "mask_iou": "dcseg.assign.masks",
    "match_view": "dcseg.assign.matching",
    "view_matches": "dcseg.assign.stage",
}

__getattr__, __dir__ = lazy_exports(__name__, _HOME, __all__)
