"""Cluster and label maps of every view, one read of each view's weights."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import cast

import numpy as np
import torch

from dcseg.blend import BlendWeights
from dcseg.io.run_state import ViewState
from dcseg.segment import EvidenceSum, MaskConfig, cluster_map
from dcseg.segment.views import cluster_maps, final_maps
from dcseg.types import SemanticMap

N = 6
"""Gaussians 0..5, one per pixel of a 1 x 6 view."""
MASKS = MaskConfig(min_weight=0.5, min_area_fraction=0.0)


@dataclass
class CountedView:
    """A view that counts the reads of its weights (as a view in the cache folder reads)."""

    name: str
    weights: BlendWeights
    reads: list[str] = field(default_factory=list)

    @property
    def blend(self) -> BlendWeights:
        self.reads.append(self.name)
        return self.weights


def view(name: str, ids: list[int]) -> CountedView:
    flat = torch.tensor(ids)
    blend = BlendWeights(1, len(ids), torch.arange(len(ids) + 1), flat, torch.full((N,), 0.9))
    return CountedView(name, blend)


class Reports:
    def __init__(self) -> None:
        self.calls: list[tuple[str, float, str]] = []

    def __call__(self, stage: str, fraction: float, message: str) -> None:
        self.calls.append((stage, fraction, message))


def test_cluster_maps_render_every_view_and_sum_evidence_in_the_same_pass() -> None:
    """Both views get a cluster map; only v0 has a class-aware map and adds its evidence. Each
    view's weights are read once, and each view done is reported."""
    counted = [view("v0", list(range(N))), view("v1", [5, 4, 3, 2, 1, 0])]
    views = cast("list[ViewState]", counted)
    labels = np.array([0, 0, 0, 1, 1, -1])
    classes = np.array([[1, 1, 1, 0, 0, 0]], dtype=np.int32)
    evidence = EvidenceSum(N, 2)
    report = Reports()
    semantic = {"v0": SemanticMap("v0", classes)}
    maps = cluster_maps(views, labels, MASKS, report, evidence, semantic)
    assert maps["v0"].tolist() == [[0, 0, 0, 1, 1, -1]]
    assert maps["v1"].tolist() == [[-1, 1, 1, 0, 0, 0]]
    assert [v.reads for v in counted] == [["v0"], ["v1"]]
    assert evidence.evidence.argmax(axis=1).tolist() == [1, 1, 1, 0, 0, 0]  # v0's classes
    assert evidence.views == 1 and np.allclose(evidence.evidence.sum(axis=1), 0.9)
    assert report.calls == [("masks", 0.5, "view v0"), ("masks", 1.0, "view v1")]
    again = cluster_maps(views, labels, MASKS, report, stage="refine")
    assert np.array_equal(again["v1"], maps["v1"]) and report.calls[-1][0] == "refine"


def test_final_maps_render_label_maps_from_the_gaussians_classes() -> None:
    """Label maps show each Gaussian's class; the cluster maps are rendered again only when
    cluster labels are given. Label maps pass the component filter only when asked: the
    one-pixel class 1 at pixel 5 goes with a filter of 2 pixels."""
    counted = view("v0", list(range(N)))
    views = cast("list[ViewState]", [counted])
    semantic_ids = np.array([0, 0, 0, 2, 2, 1])
    labels = np.array([0, 0, 0, 1, 1, 1])
    first = {"v0": np.zeros((1, N), np.int32)}
    report = Reports()
    filtered = MaskConfig(min_weight=0.5, min_area_fraction=2 / N)
    clusters, classes = final_maps(views, None, first, semantic_ids, filtered, False, report)
    assert clusters is first and classes["v0"].tolist() == [[0, 0, 0, 2, 2, 1]]
    assert report.calls == [("refine", 1.0, "view v0")]
    clusters, classes = final_maps(views, labels, first, semantic_ids, filtered, True, report)
    assert clusters["v0"].tolist() == cluster_map(counted.weights, labels, filtered).tolist()
    assert classes["v0"].tolist() == [[0, 0, 0, 2, 2, -1]]
    assert counted.reads == ["v0", "v0"]  # once per call


def test_evidence_sum_says_how_much_of_each_gaussian_fell_on_unlabelled_pixels() -> None:
    """Gaussian 5 covers an unlabelled pixel in one view and a labelled one in the other: half
    its weight is unlabelled; Gaussian 0 never reaches a labelled pixel; a Gaussian no view
    covers has a share of 0."""
    blend = BlendWeights(1, N, torch.arange(N + 1), torch.arange(N), torch.full((N,), 0.9))
    total = EvidenceSum(N + 1, 2)
    total.add(blend, np.array([[-1, 0, 0, 1, 1, -1]]))
    total.add(blend, np.array([[-1, 0, 0, 1, 1, 1]]))
    assert np.allclose(total.seen, [1.8] * N + [0.0])
    assert np.allclose(total.unlabelled_share(), [1.0, 0, 0, 0, 0, 0.5, 0.0])
