"""Parameters of the affinity stage: a stdlib dataclass, never importing torch.

The defaults are the ``paper`` values (method doc Part A §3 and §8, SAGA's
``train_contrastive_feature.py`` as run by DCSEG); :data:`PRESETS` holds the named variants.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from dcseg.fields import option


@dataclass(frozen=True)
class AffinityConfig:
    """How scale-gated contrastive affinity features are trained on frozen Gaussians."""

    feature_dim: int = option(32, bounds=(1, 256))
    """Feature channels D per Gaussian (= outputs of the scale gate)."""

    iterations: int = option(10_000, bounds=(0, 100000))
    """Optimisation steps; one random view with masks per step (without replacement per epoch).
    At the reference size (40 views): runs grow it with their views
    (:func:`dcseg.sizes.grown_steps`)."""

    rays: int = option(1000, bounds=(1, 100000))
    """Pixels sampled per step among the pixels covered by at least one mask."""

    random_scales: int = option(8, bounds=(0, 256))
    """Scale samples drawn from random masks per step; plus one above-max and one smallest."""

    lr: float = option(0.0025, bounds=(1e-08, 1.0))
    """Adam learning rate of the features and the gate (constant)."""

    adam_eps: float = option(1e-15, bounds=(1e-20, 1.0))
    """Adam epsilon."""

    init_std: float = option(0.01, bounds=(1e-08, 10.0))
    """Features start as ``N(0, 1) * init_std``."""

    knn_k: int = option(16, bounds=(1, 128))
    """Neighbours (the Gaussian itself included) of the 3D KNN feature smoothing."""

    knn_sample: int = option(8, bounds=(1, 128))
    """Neighbour slots averaged per training step (same random slots for every Gaussian)."""

    pos_threshold: float = option(0.75, bounds=(-1.0, 1.0))
    """Hard-positive mining: pairs with affinity 1 and cosine below this are kept."""

    neg_threshold: float = option(0.5, bounds=(-1.0, 1.0))
    """Hard-negative mining: pairs with affinity 0 and cosine above this are kept."""

    max_pair_weight: float = option(10.0, bounds=(1.0, 1000.0))
    """Pair weights are min-max rescaled to ``[1, max_pair_weight]``."""

    norm_weight: float = option(1.0, bounds=(0.0, 100.0))
    """Weight of ``(1 - mean ||F(p)||)^2`` over the sampled pixels (SAGA's ``rfn``)."""

    n_quantiles: int = option(1000, bounds=(1, 100000))
    """Quantiles of the scale normalisation (sklearn ``QuantileTransformer`` default)."""

    min_scale_points: int = option(10, bounds=(2, 1000000))
    """A mask with fewer valid 3D points (after erosion) has no scale and is not used."""

    min_mask_score: float = option(
        0.0,
        bounds=(0.0, 1.0),
        help="drop class-agnostic masks whose detector score is below this (0 = keep all)",
        flag="--min-mask-score",
    )
    """Class-agnostic masks whose detector ``score`` (COCO results, ``.npz`` ``scores``) is below
    this do not train the features; 0 = keep all (:mod:`dcseg.io.mask_formats.scores`)."""

    min_predicted_iou: float = option(
        0.0,
        bounds=(0.0, 1.0),
        help="drop SAM masks whose predicted_iou is below this (0 = keep all)",
        flag="--min-predicted-iou",
    )
    """Likewise for SAM's ``predicted_iou`` (SAM ``amg.py`` already drops masks below 0.88)."""

    min_stability_score: float = option(
        0.0,
        bounds=(0.0, 1.0),
        help="drop SAM masks whose stability_score is below this (0 = keep all)",
        flag="--min-stability-score",
    )
    """Likewise for SAM's ``stability_score`` (``amg.py`` already drops masks below 0.95)."""

    seed: int = option(0, fixed=True)
    """Seed of every random choice (initialisation, views, pixels, scales, pair sampling)."""

    def __post_init__(self) -> None:
        positive = ("feature_dim", "rays", "knn_k", "knn_sample", "n_quantiles")
        for name in positive:
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if self.iterations < 0:
            raise ValueError(f"iterations must be >= 0, got {self.iterations}")
        if self.random_scales < 0:
            raise ValueError(f"random_scales must be >= 0, got {self.random_scales}")
        if self.knn_sample > self.knn_k:
            raise ValueError(f"knn_sample ({self.knn_sample}) must be at most knn_k ({self.knn_k})")
        if self.lr <= 0 or self.adam_eps <= 0 or self.init_std <= 0:
            raise ValueError("lr, adam_eps and init_std must be > 0")
        if not -1.0 <= self.neg_threshold <= 1.0 or not -1.0 <= self.pos_threshold <= 1.0:
            raise ValueError("pos_threshold and neg_threshold must be in [-1, 1]")
        if self.max_pair_weight < 1.0:
            raise ValueError(f"max_pair_weight must be >= 1, got {self.max_pair_weight}")
        if self.norm_weight < 0:
            raise ValueError(f"norm_weight must be >= 0, got {self.norm_weight}")
        if self.min_scale_points < 2:
            raise ValueError(f"min_scale_points must be >= 2, got {self.min_scale_points}")
        for name in ("min_mask_score", "min_predicted_iou", "min_stability_score"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"{name} must be in [0, 1], got {getattr(self, name)}")


PAPER = AffinityConfig()
"""SAGA as run by DCSEG: 10k steps, 1000 rays, D = 32, K = 16 (8 per step)."""

FAST = replace(PAPER, iterations=1000, lr=0.005)
"""About 2 minutes on 2 CPU cores: 1000 steps at twice the paper's learning rate. Measured on the
40-view default-noise synthetic scene (projection mIoU at scale 0.5): 1000 steps at lr 0.005
83.2, 2000 steps at 0.0025 81.3 (twice the time), 1000 steps with 500 rays at 0.0025 74.4."""

PRESETS: dict[str, AffinityConfig] = {"fast": FAST, "paper": PAPER}
"""Named configurations."""
