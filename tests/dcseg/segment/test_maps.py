"""Cluster maps and label maps from blending weights."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from dcseg.blend import BlendWeights
from dcseg.segment import MaskConfig, cluster_map, label_map
from dcseg.segment.config import PAPER_MIN_AREA_FRACTION


def one_per_pixel(ids: list[list[int]], weight: float = 0.9) -> BlendWeights:
    """A view where every pixel sees exactly one Gaussian (id = pixel's value)."""
    flat = torch.tensor(ids).reshape(-1)
    height, width = len(ids), len(ids[0])
    offsets = torch.arange(height * width + 1)
    return BlendWeights(height, width, offsets, flat, torch.full((flat.numel(),), weight))


def test_cluster_map_dominant_then_cleaned() -> None:
    # Gaussians 0-3; clusters: 0 -> 0, 1 -> 0, 2 -> 1, 3 -> noise.
    blend = one_per_pixel([[0, 1, 2, 2], [0, 1, 2, 3], [0, 1, 1, 3]])
    labels = np.array([0, 0, 1, -1])
    cfg = MaskConfig(min_weight=0.5, min_area_fraction=0.0)
    assert cluster_map(blend, labels, cfg).tolist() == [[0, 0, 1, 1], [0, 0, 1, -1], [0, 0, 0, -1]]
    # A 3-pixel cluster is a fragment below 4/12 of the image: cleaned away.
    cleaned = cluster_map(blend, labels, MaskConfig(min_area_fraction=4 / 12))
    assert (cleaned == 1).sum() == 0 and (cleaned == 0).sum() == 7


def test_cluster_map_threshold() -> None:
    blend = one_per_pixel([[0, 1]], weight=0.4)
    out = cluster_map(blend, np.array([0, 1]), MaskConfig(min_weight=0.5, min_area_fraction=0))
    assert out.tolist() == [[-1, -1]]


def test_label_map_keeps_none() -> None:
    clusters = np.array([[-1, 0], [1, 2]])
    assert label_map(clusters, np.array([3, -1, 0])).tolist() == [[-1, 3], [-1, 0]]


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [({"min_weight": 0.0}, "min_weight"), ({"min_area_fraction": 1.0}, "min_area")],
)
def test_mask_config_rejects(kwargs: dict[str, float], match: str) -> None:
    with pytest.raises(ValueError, match=match):
        MaskConfig(**kwargs)


def test_min_area_scales_with_image() -> None:
    paper = MaskConfig(min_area_fraction=PAPER_MIN_AREA_FRACTION)
    assert paper.min_area(1200, 680) == 1000
    assert paper.min_area(320, 240) == 94
    assert MaskConfig().min_area(1200, 680) == 82
    assert MaskConfig().min_area(320, 240) == 8
