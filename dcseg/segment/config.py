"""Parameters of the cluster-mask stage (stdlib only: never imports torch)."""

from __future__ import annotations

from dataclasses import dataclass

PAPER_MIN_AREA_FRACTION = 1000 / (1200 * 680)
"""The paper's 2D filter (1000 px at Replica's 1200x680) as a fraction of the image."""


@dataclass(frozen=True)
class MaskConfig:
    """How clusters become per-view instance maps (method doc §5, Part B §5).

    Attributes:
        min_weight: a pixel belongs to the cluster with the largest accumulated blending weight
            when that weight is at least this (Part B §5: a fixed threshold instead of the
            original random-palette colour sum, whose effective threshold was 0.19-1.84 with
            median 0.5/1.53 = 0.33, method doc §5). 0.33 measured better than 0.5 on a 16-view
            synthetic scene (projection mIoU 0.66 vs 0.60): floaters outside any cluster take
            part of a pixel's weight.
        min_area_fraction: 2D connected-component filter (8-connectivity): components smaller
            than this fraction of the image are removed. The paper's 1000 px at 1200x680
            (:data:`PAPER_MIN_AREA_FRACTION`, 0.00123) erases small objects entirely (94 px at
            320x240, more than a toy brick covers). 0.0001 (8 px at 320x240, 82 px at
            1200x680): projection mIoU on the 40-view synthetic benchmark scenes, mean over
            three reconstructions x clustering seeds 0/10 (``benchmarks/bench_robustness.py``),
            clean / default / heavy noise, for 0.0003 / 0.0002 / 0.00015 / 0.0001 / 0.00005 /
            0: 87.7 / 88.4 / 88.2 / 88.0 / 87.8 / 87.9, 83.0 / 83.5 / 85.0 / 86.0 / 86.6 /
            86.6, 73.2 / 75.6 / 76.4 / 78.1 / 78.3 / 78.0 — the smallest objects lose pixels
            in every view they are partly hidden in, and below 0.0001 the filter hardly
            matters. (0.0003 had looked best on one clean run, within its noise.)
    """

    min_weight: float = 0.33
    min_area_fraction: float = 0.0001

    def __post_init__(self) -> None:
        if not 0.0 < self.min_weight <= 1.0:
            raise ValueError(f"min_weight must be in (0, 1], got {self.min_weight}")
        if not 0.0 <= self.min_area_fraction < 1.0:
            raise ValueError(f"min_area_fraction must be in [0, 1), got {self.min_area_fraction}")

    def min_area(self, width: int, height: int) -> int:
        """The filter's area in pixels for a ``width`` x ``height`` view."""
        return round(self.min_area_fraction * width * height)
