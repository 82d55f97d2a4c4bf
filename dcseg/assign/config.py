"""Parameters of the assignment stage (stdlib only: this module must never import torch)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

AssignMode = Literal["assignment", "matching"]


@dataclass(frozen=True)
class AssignConfig:
    """How clusters get class labels from per-view class-aware 2D masks (method doc §6, B.7).

    Attributes:
        mode: ``"assignment"`` (each class may take up to ``replicas`` clusters per view; the
            paper's best variant) or ``"matching"`` (one-to-one; the ablation).
        replicas: class replicas per view in ``"assignment"`` mode: a fixed count (paper: 3)
            or ``"components"`` = the number of connected components of the class's mask in
            that view with at least ``min_area`` pixels (1 for a class that is present only in
            smaller pieces).
        min_iou: edges with IoU below this are invalid: never matched, never voted (paper 0.05).
        min_area: smallest class-mask component (pixels) counted by ``replicas="components"``.
            The same-named 2D filter of cluster masks (paper: 1000 px at 1200x680) is applied
            before this stage, when cluster maps are made.
        min_share_ratio: after voting, a Gaussian of a labelled cluster leaves the cluster
            (becomes noise) when its own class-mask evidence — its blending weight over the
            pixels of each class, summed over views — gives the cluster's class a share below
            this fraction of the share the whole cluster gives it
            (:mod:`dcseg.assign.consistency`); 0 = off (the paper). dcseg's addition: on the
            40-view synthetic benchmark scenes, object clusters also held floor Gaussians up to
            half a metre away, labelling floor as ball, block or domino. Projection mIoU, mean
            over three reconstructions (pipeline seeds 0/1/2) x clustering seeds 0/10
            (``benchmarks/bench_robustness.py``), clean / default / heavy noise, off vs 0.5 vs
            0.6: 87.6 / 81.7 / 69.3 vs 88.0 / 86.0 / 78.1 vs 88.5 / 86.7 / 78.0. An absolute
            share floor instead (0.15; measured with the older 2D filter) erased a rare class
            that the maps miss in most views, which the relative test keeps; 0.7 started to
            erase it too, so the default stays clear of that edge.
    """

    mode: AssignMode = "assignment"
    replicas: int | Literal["components"] = 3
    min_iou: float = 0.05
    min_area: int = 1000
    min_share_ratio: float = 0.5

    def __post_init__(self) -> None:
        if self.mode not in ("assignment", "matching"):
            raise ValueError(f"mode must be 'assignment' or 'matching', got {self.mode!r}")
        if self.replicas != "components" and not (
            isinstance(self.replicas, int) and self.replicas >= 1
        ):
            raise ValueError(f"replicas must be an int >= 1 or 'components', got {self.replicas!r}")
        if not 0.0 < self.min_iou <= 1.0:
            raise ValueError(f"min_iou must be in (0, 1], got {self.min_iou}")
        if not 0.0 <= self.min_share_ratio <= 1.0:
            raise ValueError(f"min_share_ratio must be in [0, 1], got {self.min_share_ratio}")
        if self.min_area < 0:
            raise ValueError(f"min_area must be >= 0, got {self.min_area}")
