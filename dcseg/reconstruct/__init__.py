"""Stage 1: posed RGB-D frames to optimised 3D Gaussians.

``fit_gaussians(capture, cfg)`` initialises Gaussians from back-projected depth
(:func:`init_from_capture`), optimises them against the training frames with an RGB
(L1 + D-SSIM) and a depth loss, with 3DGS density control, and evaluates held-out frames.

Importing this package (or :mod:`dcseg.reconstruct.config`) does not import torch: the
torch-based names are loaded on first access (PEP 562), so the service can read the config.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from dcseg._lazy import lazy_exports
from dcseg.reconstruct.config import PRESETS, ReconstructConfig

if TYPE_CHECKING:
    from dcseg.reconstruct.evaluate import Metrics, ViewMetrics
    from dcseg.reconstruct.fit import ProgressCallback
    from dcseg.reconstruct.init import init_from_capture
    from dcseg.reconstruct.stage import Reconstruction, fit_gaussians

__all__ = [
    "PRESETS",
    "Metrics",
    "ProgressCallback",
    "ReconstructConfig",
    "Reconstruction",
    "ViewMetrics",
    "fit_gaussians",
    "init_from_capture",
]

_LAZY = {
    "Metrics": "dcseg.reconstruct.evaluate",
    "ViewMetrics": "dcseg.reconstruct.evaluate",
    "ProgressCallback": "dcseg.reconstruct.fit",
    "init_from_capture": "dcseg.reconstruct.init",
    "Reconstruction": "dcseg.reconstruct.stage",
    "fit_gaussians": "dcseg.reconstruct.stage",
}


__getattr__, __dir__ = lazy_exports(__name__, _LAZY, __all__)
