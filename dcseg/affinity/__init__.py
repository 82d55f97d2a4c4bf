"""Stage 2: scale-gated contrastive affinity features per Gaussian (SAGA, method doc §3).

``train_affinity(gaussians, views, cfg)`` learns a D-dimensional feature per frozen Gaussian and a
scale gate from posed views with class-agnostic 2D masks; ``gated_features(result, s)`` gives the
unit vectors to cluster at quantile scale ``s`` (the paper uses 0.8). ``AffinityConfig`` and the
``paper``/``fast`` presets live in :mod:`dcseg.affinity.config`.

The exports are resolved lazily (PEP 562) so that ``import dcseg.affinity.config`` stays
torch-free: the HTTP service imports configs without torch.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from dcseg._lazy import lazy_exports

if TYPE_CHECKING:
    from dcseg.affinity.data import AffinityResult, AffinityView, gated_features
    from dcseg.affinity.scales import mask_scales
    from dcseg.affinity.train import train_affinity

__all__ = [
    "AffinityResult",
    "AffinityView",
    "gated_features",
    "mask_scales",
    "train_affinity",
]

_HOME = {
    "AffinityResult": "dcseg.affinity.data",
    "AffinityView": "dcseg.affinity.data",
    "gated_features": "dcseg.affinity.data",
    "mask_scales": "dcseg.affinity.scales",
    "train_affinity": "dcseg.affinity.train",
}


__getattr__, __dir__ = lazy_exports(__name__, _HOME, __all__)
