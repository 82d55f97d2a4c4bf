"""Stage 3: clusters of Gaussians rendered into every view as instance maps, and label maps.

Both are sparse products over a view's frozen blending weights (:class:`dcseg.blend.BlendWeights`):
one pass for all clusters, never one render per cluster. Exports resolve lazily (PEP 562) so that
``dcseg.segment.config`` stays torch-free.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from dcseg.segment.config import MaskConfig
    from dcseg.segment.maps import cluster_map, label_map

__all__ = ["MaskConfig", "cluster_map", "label_map"]

_HOME = {
    "MaskConfig": "dcseg.segment.config",
    "cluster_map": "dcseg.segment.maps",
    "label_map": "dcseg.segment.maps",
}


def __getattr__(name: str) -> Any:
    if name not in _HOME:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(_HOME[name]), name)


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
