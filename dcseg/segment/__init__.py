"""Stage 3: clusters of Gaussians rendered into every view as instance maps, and label maps.

Both are sparse products over a view's frozen blending weights (:class:`dcseg.blend.BlendWeights`):
one pass for all clusters, never one render per cluster. Exports resolve lazily (PEP 562) so that
``dcseg.segment.config`` stays torch-free.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from dcseg._lazy import lazy_exports

if TYPE_CHECKING:
    from dcseg.segment.config import MaskConfig
    from dcseg.segment.evidence import EvidenceSum, class_agreement, class_evidence, vote_3d
    from dcseg.segment.maps import cluster_map, label_map

__all__ = [
    "EvidenceSum",
    "MaskConfig",
    "class_agreement",
    "class_evidence",
    "cluster_map",
    "label_map",
    "vote_3d",
]

_HOME = {
    "EvidenceSum": "dcseg.segment.evidence",
    "MaskConfig": "dcseg.segment.config",
    "class_agreement": "dcseg.segment.evidence",
    "class_evidence": "dcseg.segment.evidence",
    "vote_3d": "dcseg.segment.evidence",
    "cluster_map": "dcseg.segment.maps",
    "label_map": "dcseg.segment.maps",
}


__getattr__, __dir__ = lazy_exports(__name__, _HOME, __all__)
