"""Parameters of the evaluation stage (stdlib only: this module must never import torch)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

PointProtocol = Literal["projection", "nearest"]


@dataclass(frozen=True)
class EvaluateConfig:
    """How predictions reach ground-truth points and how metrics are aggregated (§7, B.10).

    Attributes:
        protocol: how the pipeline labels ground-truth points: ``"projection"`` (the paper's:
            per-view label images, depth-agreement test, majority vote; see
            :func:`~dcseg.evaluate.points.vote_projection`) or ``"nearest"`` (nearest labelled
            Gaussian; :func:`~dcseg.evaluate.points.transfer_nearest`).
        depth_tol: projection protocol: a view votes for a point only when the point's depth
            and the view's depth at its pixel differ by less than this (metres; paper 0.1).
        max_distance: nearest protocol: points farther than this (world units) from every
            Gaussian above ``min_opacity`` get no prediction (evaluation protocol: 5 cm).
        min_opacity: nearest protocol: only Gaussians above this opacity carry labels to
            ground-truth points (near-transparent ones are not what a viewer shows).
        split: name of a class split in :data:`~dcseg.evaluate.stage.SPLITS` (``"replica"``:
            head/common/tail) for per-split means; None = no split means.
    """

    protocol: PointProtocol = "projection"
    depth_tol: float = 0.1
    max_distance: float = 0.05
    min_opacity: float = 0.05
    split: str | None = None

    def __post_init__(self) -> None:
        if self.protocol not in ("projection", "nearest"):
            raise ValueError(f"protocol must be 'projection' or 'nearest', got {self.protocol!r}")
        if self.depth_tol <= 0:
            raise ValueError(f"depth_tol must be > 0, got {self.depth_tol}")
        if self.max_distance <= 0:
            raise ValueError(f"max_distance must be > 0, got {self.max_distance}")
        if not 0 <= self.min_opacity < 1:
            raise ValueError(f"min_opacity must be in [0, 1), got {self.min_opacity}")
