"""Stage: label clusters with classes from class-aware 2D maps (method doc §6, Part B.7).

Entry point: :func:`assign_labels`. Masks arrive as dense ``[H, W]`` int label maps (-1 = none):
cluster-id maps rendered from the clustering, class maps from ``SemanticMap.classes``.
"""

from dcseg.assign.config import AssignConfig
from dcseg.assign.consistency import inconsistent
from dcseg.assign.masks import clean_cluster_map, component_counts, mask_iou
from dcseg.assign.matching import Match, class_replicas, match_view
from dcseg.assign.stage import Assignment, assign_labels, view_matches
from dcseg.assign.vote import decide, tally, vote

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
