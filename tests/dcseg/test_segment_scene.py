"""segment_scene on a hand-made scene: what the rendered label maps show.

Clustering is fixed (``cluster_features`` and ``gated_features`` are replaced) so the test is
about what follows it: voting, the consistency step, label completion and the maps.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
import pytest
import torch

from dcseg.assign.stage import Assignment
from dcseg.blend import BlendWeights
from dcseg.cluster.features import Clustering
from dcseg.config import PipelineConfig, preset
from dcseg.gaussians import Gaussians
from dcseg.io.run_state import ViewState
from dcseg.pipeline import TrainedScene, segment_scene
from dcseg.segment import cluster_map, label_map
from dcseg.types import SemanticMap

N = 12
"""Gaussians 0..11 on a line, one per pixel of a 1 x 12 view."""
CLUSTERS = np.array([0] * 8 + [1] * 4)
"""Cluster 0 holds Gaussians 0-7, though 6 and 7 sit on what the class maps call class 1."""
CLASSES = np.array([[0] * 6 + [1] * 6], dtype=np.int32)
"""The class-aware map of every view: pixels 0-5 class 0, 6-11 class 1."""


def scene(n_views: int = 2) -> TrainedScene:
    means = torch.zeros(N, 3, dtype=torch.float64)
    means[:, 0] = torch.arange(N, dtype=torch.float64)
    gaussians = Gaussians(
        means,
        torch.tensor([[1.0, 0.0, 0.0, 0.0]]).repeat(N, 1).double(),
        torch.zeros(N, 3, dtype=torch.float64),
        torch.full((N,), 3.0, dtype=torch.float64),
        torch.zeros(N, 1, 3, dtype=torch.float64),
    )
    blend = BlendWeights(1, N, torch.arange(N + 1), torch.arange(N), torch.full((N,), 0.9))
    views = tuple(
        ViewState.in_memory(f"v{i}", np.eye(3), np.eye(4), blend, np.ones((1, N), np.float32))
        for i in range(n_views)
    )
    return TrainedScene(gaussians, None, views)  # type: ignore[arg-type]


@pytest.fixture(autouse=True)
def fixed_clusters(monkeypatch: pytest.MonkeyPatch) -> None:
    centers = np.eye(2, dtype=np.float32)

    def clusters(*args: Any, **kwargs: Any) -> Clustering:
        return Clustering(CLUSTERS.copy(), centers, np.ones(N, dtype=np.float32))

    features = np.tile(np.array([1.0, 0.0], np.float32), (N, 1))
    monkeypatch.setattr("dcseg.pipeline.gated_features", lambda affinity, scale: features)
    monkeypatch.setattr("dcseg.pipeline.cluster_features", clusters)


def config(label_maps: str, **assign: Any) -> PipelineConfig:
    cfg = preset("fast")
    changes = {"objects": False, "label_maps": label_maps, **assign}
    return replace(cfg, assign=replace(cfg.assign, **changes))


def segment(cfg: PipelineConfig) -> Any:
    trained = scene()
    semantic = {v.name: SemanticMap(v.name, CLASSES) for v in trained.views}
    return segment_scene(trained, semantic, 2, cfg)


def test_label_maps_show_the_gaussians_final_classes() -> None:
    """Gaussians 6-7 leave cluster 0 (their own evidence says class 1, the cluster's class is
    0) and completion gives them class 1: the maps rendered from the Gaussians show it; the
    cluster maps through each cluster's class leave their pixels unlabelled."""
    new, old = segment(config("gaussians")), segment(config("clusters"))
    assert new.assignment.labels.tolist() == [0, 1] == old.assignment.labels.tolist()
    assert new.semantic_ids.tolist() == [0] * 6 + [1] * 6  # consistency, then completion
    assert np.array_equal(new.semantic_ids, old.semantic_ids)  # the option changes maps only
    for name in ("v0", "v1"):
        assert new.label_maps[name].tolist() == CLASSES.tolist()
        assert old.label_maps[name].tolist() == [[0] * 6 + [-1] * 2 + [1] * 4]
        # the cluster level is the same either way: rendered from the refined clusters
        assert np.array_equal(new.cluster_maps[name], old.cluster_maps[name])
        assert new.cluster_maps[name].tolist() == [[0] * 6 + [-1] * 2 + [1] * 4]


def test_label_maps_follow_completion_without_the_consistency_step() -> None:
    """With the consistency step off, cluster 0 keeps Gaussians 6-7 and its class 0; the maps
    from the Gaussians agree with the per-Gaussian classes pixel by pixel, and the cluster
    maps are the first ones (no second render)."""
    cfg = config("gaussians", min_share_ratio=0.0)
    seg = segment(cfg)
    assert seg.semantic_ids.tolist() == [0] * 8 + [1] * 4
    blend = scene().views[0].blend
    for name, classes in seg.label_maps.items():
        assert np.array_equal(classes, cluster_map(blend, seg.semantic_ids, cfg.masks))
        assert np.array_equal(classes, label_map(seg.cluster_maps[name], seg.assignment.labels))


def test_label_maps_is_checked() -> None:
    with pytest.raises(ValueError, match="label_maps"):
        replace(preset("fast").assign, label_maps="pixels")  # type: ignore[arg-type]


@pytest.mark.parametrize("label_maps", ["gaussians", "clusters"])
def test_per_view_maps_are_held_as_int32(label_maps: str) -> None:
    """A run holds two maps per view; int32 halves what int64 would take (2.5 MB per map and
    view at 640x480)."""
    seg = segment(config(label_maps))
    for maps in (seg.cluster_maps, seg.label_maps):
        assert {m.dtype for m in maps.values()} == {np.dtype(np.int32)}
    assert seg.instance_map("v0").tolist()[0][:6] == [0] * 6


def test_masks_that_agree_everywhere_let_each_gaussian_follow_its_own_evidence(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Gaussians 0-9 form cluster 0 (class 0), 11 cluster 1 (class 1), 10 is noise. Pixel 10
    is class 1 in four of five views and class 0 in one; every other pixel is the same in all
    views, so the masks agree with the labelled clusters everywhere (agreement 1.0). Completion
    gives Gaussian 10 its neighbours' class 0 (7 of its 8 neighbours) when evidence is not
    trusted, and class 1 (its own evidence, 0.8) when it is."""
    clusters = np.array([0] * 10 + [-1, 1])

    def fixed(*args: Any, **kwargs: Any) -> Clustering:
        return Clustering(clusters.copy(), np.eye(2, dtype=np.float32), np.ones(N, np.float32))

    monkeypatch.setattr("dcseg.pipeline.cluster_features", fixed)
    trained = scene(n_views=5)
    semantic = {}
    for i, view in enumerate(trained.views):
        classes = np.array([[0] * 10 + [1 if i else 0, 1]], dtype=np.int32)
        semantic[view.name] = SemanticMap(view.name, classes)

    def run(**assign: Any) -> Any:
        return segment_scene(trained, semantic, 2, config("gaussians", **assign))

    trusted, plain = run(), run(trust_agreement=None)
    assert trusted.mask_agreement == pytest.approx(1.0) == plain.mask_agreement
    assert trusted.evidence_trusted and not plain.evidence_trusted
    assert trusted.semantic_ids.tolist() == [0] * 10 + [1, 1]
    assert plain.semantic_ids.tolist() == [0] * 10 + [0, 1]
    weak = {"trust_agreement": 1.0 - 1e-9, "trusted_evidence_weight": 1.0}
    assert not run(**weak, trusted_follow_ratio=0.0).semantic_ids[10]  # completion alone
    # completion gave it the neighbours' class; its own trusted evidence then wins
    assert run(**weak).semantic_ids[10] == 1
    assert run(trust_agreement=None, follow_evidence_ratio=0.9).semantic_ids[10] == 1


def test_masks_that_disagree_keep_cluster_decisions() -> None:
    """The module's scene: Gaussians 6-7 of cluster 0 sit on class-1 pixels, agreement 10/12."""
    seg = segment(config("gaussians"))
    assert seg.mask_agreement == pytest.approx(10 / 12)
    assert not seg.evidence_trusted


@pytest.mark.parametrize("filtered", [True, False])
def test_label_maps_keep_small_objects_unless_filtered(filtered: bool) -> None:
    """View v1 sees cluster 1 (class 1) over 2 pixels only (pixels 10-11 show Gaussian 7, a
    2-pixel piece of cluster 0): a component filter of 3 pixels erases both pieces from its
    cluster map, and from its label map only when ``filter_label_maps`` is on; view v0
    (4 pixels) keeps class 1 either way."""
    trained = scene()
    ids = torch.tensor([*range(10), 7, 7])
    far = BlendWeights(1, N, torch.arange(N + 1), ids, torch.full((N,), 0.9))
    v1 = ViewState.in_memory("v1", np.eye(3), np.eye(4), far, np.ones((1, N), np.float32))
    trained = TrainedScene(trained.gaussians, None, (trained.views[0], v1))  # type: ignore[arg-type]
    semantic = {v.name: SemanticMap(v.name, CLASSES) for v in trained.views}
    cfg = config("gaussians", min_share_ratio=0.0, filter_label_maps=filtered)
    cfg = replace(cfg, masks=replace(cfg.masks, min_area_fraction=0.25))
    seg = segment_scene(trained, semantic, 2, cfg)
    assert seg.semantic_ids.tolist() == [0] * 8 + [1] * 4
    assert seg.label_maps["v0"].tolist() == [[0] * 8 + [1] * 4]
    assert seg.cluster_maps["v1"].tolist() == [[0] * 8 + [-1] * 4]
    small = [-1] * 4 if filtered else [1, 1, 0, 0]
    assert seg.label_maps["v1"].tolist() == [[0] * 8 + small]


def one_cluster(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every Gaussian in cluster 0."""

    def fixed(*args: Any, **kwargs: Any) -> Clustering:
        return Clustering(
            np.zeros(N, np.int64), np.eye(1, 2, dtype=np.float32), np.ones(N, np.float32)
        )

    monkeypatch.setattr("dcseg.pipeline.cluster_features", fixed)


@pytest.mark.parametrize(("min_size", "duck"), [(3, 1), (4, 0), (0, 0)])
def test_an_object_that_leaves_its_support_cluster_keeps_its_class(
    monkeypatch: pytest.MonkeyPatch, min_size: int, duck: int
) -> None:
    """A duck on a tray, merged into one cluster by the class-agnostic masks: Gaussians 4-6 sit
    on class-1 pixels of a cluster voted class 0. They leave it (consistency step); as a
    touching group of 3 they become a cluster of class 1 when ``regroup_min_gaussians`` <= 3.
    Otherwise they are noise, and completion from the tray around them gives them the tray's
    class."""
    one_cluster(monkeypatch)
    trained = scene()
    classes = np.array([[0] * 4 + [1] * 3 + [0] * 5], dtype=np.int32)
    semantic = {v.name: SemanticMap(v.name, classes) for v in trained.views}
    cfg = config("gaussians", regroup_min_gaussians=min_size)
    seg = segment_scene(trained, semantic, 2, cfg)
    assert seg.semantic_ids.tolist() == [0] * 4 + [duck] * 3 + [0] * 5
    if duck:  # the group is a cluster of its own, class 1 by all of its evidence
        assert seg.clustering.labels.tolist() == [0] * 4 + [1] * 3 + [0] * 5
        assert seg.assignment.labels.tolist() == [0, 1]
        assert seg.assignment.scores[1] == 1.0 and seg.assignment.n_views[1] == 0
    else:
        assert (seg.clustering.labels[4:7] == -1).all()
        assert seg.assignment.labels.tolist() == [0]


@pytest.mark.parametrize(
    ("support", "extent", "floor"), [(0.1, 0.5, 0), (0.0, 0.5, 1), (0.1, 7.0, 1)]
)
def test_a_vote_its_cluster_evidence_does_not_support_takes_the_supported_class(
    monkeypatch: pytest.MonkeyPatch, support: float, extent: float, floor: int
) -> None:
    """Cluster 0 (Gaussians 0-7, all on class-0 pixels; the fixture's clusters and a map with
    classes 0 | 1 at pixels 0-7 | 8-11) voted class 1 by the masks: its own evidence gives
    class 1 nothing, so with ``min_cluster_support`` > 0 it takes class 0. With 0 the vote
    stands, and no Gaussian of the cluster leaves it (none has a share below the cluster's).
    The cluster spans 7 units less its tails (6.3): with ``support_min_extent`` 7 it counts
    as a small object that the maps may miss, and its vote stands too."""

    def voted(*args: Any, **kwargs: Any) -> Assignment:
        return Assignment(np.array([1, 1]), np.ones(2), np.array([[0.0, 2.0], [0.0, 2.0]]),
                          np.array([2, 2]))  # fmt: skip

    monkeypatch.setattr("dcseg.pipeline.assign_labels", voted)
    trained = scene()
    classes = np.array([[0] * 8 + [1] * 4], dtype=np.int32)
    semantic = {v.name: SemanticMap(v.name, classes) for v in trained.views}
    cfg = config("gaussians", min_cluster_support=support, support_min_extent=extent)
    seg = segment_scene(trained, semantic, 2, cfg)
    assert seg.assignment.labels.tolist() == [floor, 1]
    assert seg.semantic_ids.tolist() == [floor] * 8 + [1] * 4
    # the new class's share of the cluster's votes: the masks never voted class 0 for it
    assert seg.assignment.scores[0] == (1.0 if floor else 0.0)


def test_what_the_class_masks_leave_unlabelled_stays_unlabelled(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Masks that label only the object (pixels 0-3), the rest left unlabelled (ground-truth
    label images with 0 = background). The object's cluster also took Gaussians 4-5 of the
    background; the background's cluster (6-11) touches it. Before ``background_share`` the
    background adopted the object's class and 4-5 kept it; now neither has a class.
    ``background_share`` 1 is the old behaviour."""
    clusters = np.array([0] * 6 + [1] * 6)
    monkeypatch.setattr(
        "dcseg.pipeline.cluster_features",
        lambda *a, **k: Clustering(
            clusters.copy(), np.eye(2, dtype=np.float32), np.ones(N, np.float32)
        ),
    )
    trained = scene()
    only_object = np.array([[0] * 4 + [-1] * 8], dtype=np.int32)
    semantic = {v.name: SemanticMap(v.name, only_object) for v in trained.views}
    cfg = config("gaussians", objects=True, min_instance_gaussians=1)
    seg = segment_scene(trained, semantic, 2, cfg)
    assert seg.assignment.labels.tolist() == [0, -1]
    assert seg.semantic_ids.tolist() == [0] * 4 + [-1] * 8
    assert seg.instances.ids.tolist() == [0] * 4 + [-1] * 8 and seg.background == 8
    old = segment_scene(
        trained, semantic, 2, replace(cfg, assign=replace(cfg.assign, background_share=1.0))
    )
    assert old.semantic_ids.tolist() == [0] * N and old.instances.ids.tolist() == [0] * N
