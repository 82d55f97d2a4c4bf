"""The DCSEG method, composed from its stages (method doc, Part B).

``train_scene`` does everything that needs optimisation once (blend-weight caches and affinity
features on frozen Gaussians); ``segment_scene`` clusters at a scale and classifies with
class-aware masks, cheaply, as often as wanted; ``evaluate_segmentation`` scores it.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray

from dcseg.affinity import AffinityResult, AffinityView, gated_features, train_affinity
from dcseg.assign.config import AssignConfig
from dcseg.assign.consistency import mask_agreement
from dcseg.assign.objects import build_objects, stuff_ids
from dcseg.assign.refinement import drop_inconsistent, supported_votes, trusted_settings
from dcseg.assign.rings import release_rings
from dcseg.assign.stage import Assignment, assign_labels
from dcseg.blend import BlendWeights
from dcseg.cluster.features import Clustering, as_numpy
from dcseg.cluster.outliers import adaptive_radius
from dcseg.cluster.stage import cluster_features
from dcseg.config import CacheConfig, PipelineConfig
from dcseg.evaluate.instances import instance_metrics
from dcseg.evaluate.points import transfer_opaque
from dcseg.evaluate.stage import evaluate_scenes
from dcseg.evaluate.views import vote_views
from dcseg.gaussians import Gaussians
from dcseg.io.run_state import BlendMemory, ViewState, write_view
from dcseg.progress import Progress, quiet, steps
from dcseg.reconstruct.rgbonly import with_rendered_depth
from dcseg.render import Camera
from dcseg.render.blend_weights import blend_weights
from dcseg.render.projection import quat_to_rotmat
from dcseg.segment import EvidenceSum, label_map
from dcseg.segment.views import cluster_maps, final_maps
from dcseg.segmentation import Labels, Segmentation
from dcseg.types import AgnosticMasks, Capture, GroundTruth, SemanticMap, Vocabulary


@dataclass(frozen=True)
class TrainedScene:
    """Everything a segmentation reuses: frozen Gaussians, their views and affinity features."""

    gaussians: Gaussians
    affinity: AffinityResult
    views: tuple[ViewState, ...]


def build_views(
    gaussians: Gaussians,
    capture: Capture,
    cfg: CacheConfig,
    on_progress: Progress = quiet,
    folder: Path | None = None,
) -> tuple[ViewState, ...]:
    """The blending-weight cache of every frame of the capture.

    With ``folder``, each view's weights are written to ``folder/views/<i>.npz`` as soon as
    they are computed (the run's ``state/`` layout) and at most ``cfg.memory_mb`` of them stay
    in memory (:class:`~dcseg.io.run_state.BlendMemory`): the weights held never exceed that
    budget plus the view in use, however many frames the capture has. Without ``folder`` all
    views stay in memory.
    """
    views = []
    memory = BlendMemory(cfg.memory_mb * 2**20)
    for i, frame in enumerate(capture.frames):
        camera = Camera.from_frame(frame)
        blend = blend_weights(
            gaussians, camera, min_weight=cfg.min_weight, max_per_pixel=cfg.max_per_pixel
        )
        K, c2w = frame.intrinsics.matrix(), frame.c2w.copy()
        if folder is None:
            views.append(ViewState.in_memory(frame.name, K, c2w, blend, frame.depth))
        else:
            path = folder / "views" / f"{i}.npz"
            views.append(
                write_view(path, frame.name, K, c2w, blend, frame.depth, memory, cfg.half_weights)
            )
        on_progress("cache", (i + 1) / len(capture), f"view {frame.name}: {blend.nnz} weights")
        del blend
    return tuple(views)


def train_scene(
    gaussians: Gaussians,
    capture: Capture,
    agnostic: Mapping[str, AgnosticMasks],
    cfg: PipelineConfig,
    on_progress: Progress = quiet,
    cache_dir: Path | None = None,
) -> TrainedScene:
    """Cache blending weights per view and train affinity features on the frozen Gaussians.

    Args:
        gaussians: the reconstructed scene (geometry and opacity stay frozen).
        capture: the posed RGB-D frames the masks belong to.
        agnostic: class-agnostic masks per frame name, at the frames' resolution.
        cfg: the pipeline configuration.
        on_progress: progress callback.
        cache_dir: where the cache is written (see :func:`build_views`); None = in memory.
    """
    frozen = gaussians.detach()
    capture = with_rendered_depth(capture, frozen)  # an RGB-only capture's depth: rendered
    views = build_views(frozen, capture, cfg.cache, on_progress, cache_dir)
    depth = {f.name: f.depth for f in capture.frames}  # held by the capture anyway
    inputs = [
        AffinityView(v.name, _loader(v), agnostic.get(v.name), depth[v.name], v.K) for v in views
    ]
    affinity = train_affinity(
        frozen, inputs, cfg.affinity, on_progress=steps(on_progress, "affinity")
    )
    return TrainedScene(frozen, affinity, views)


def _loader(view: ViewState) -> BlendWeights | Callable[[], BlendWeights]:
    """The view's weights, or how to read them when they live in the cache folder."""
    return view.blend if view.source is None else lambda: view.blend


def segment_scene(
    trained: TrainedScene,
    semantic: Mapping[str, SemanticMap],
    n_classes: int,
    cfg: PipelineConfig,
    on_progress: Progress = quiet,
    class_names: Sequence[str] = (),
) -> Segmentation:
    """Cluster at ``cfg.scale``, render cluster maps, label clusters, and build objects.

    When the class-aware masks agree with the labelled clusters at least
    ``cfg.assign.trust_agreement``, the trusted share ratio and evidence weight replace the
    usual ones below (:func:`~dcseg.assign.consistency.mask_agreement`). With
    ``cfg.assign.min_share_ratio > 0``, Gaussians whose own class-mask evidence
    contradicts their cluster's class then leave it (:mod:`dcseg.assign.refinement`),
    clusters left empty are removed, and the cluster maps are rendered again; the votes stay
    those of the first maps. Then unlabelled clusters adopt a touching labelled neighbour's
    class, unlabelled Gaussians on labelled surfaces are completed, and clusters become
    object instances (:mod:`dcseg.assign.objects`; ``class_names`` names the vocabulary, so
    that ``cfg.assign.stuff_classes`` can be found in it). With ``cfg.assign.label_maps ==
    "gaussians"`` the label maps are rendered from the Gaussians' final classes (those of
    ``semantic_ids``), in the same pass over the views as the second cluster maps; with
    ``"clusters"`` they are the cluster maps through each cluster's class.
    """
    features = gated_features(trained.affinity, cfg.scale)
    g = trained.gaussians
    clustering = cluster_features(features, g.means, g.opacities(), cfg.cluster)
    k = int(clustering.centers.shape[0])
    on_progress("cluster", 1.0, f"{k} clusters")
    a = cfg.assign
    labelled = [v.name for v in trained.views if v.name in semantic]
    needed = n_classes > 0 and (
        (a.min_share_ratio > 0 and bool(labelled)) or a.objects or a.complete
    )
    # the pass that renders the cluster maps also sums the class evidence that the
    # consistency step and the objects use: each view's weights are read once for both
    total = EvidenceSum(len(g.means), n_classes) if needed else None
    maps = cluster_maps(trained.views, clustering.labels, cfg.masks, on_progress, total, semantic)
    assignment = assign_labels(
        [maps[n] for n in labelled], [semantic[n].classes for n in labelled], k, n_classes,
        cfg.assign,
    )  # fmt: skip
    on_progress("assign", 1.0, f"{int((assignment.labels >= 0).sum())} of {k} clusters labelled")
    _report_consistency(assignment, on_progress)
    voted = assignment  # the vote's own record; the steps below rebuild the assignment
    evidence = None if total is None else total.evidence
    agreement = float("nan")
    means = as_numpy(g.means, np.float64)
    if evidence is not None:
        assignment, n_weak = supported_votes(evidence, clustering, assignment, means, cfg.assign)
        if n_weak:
            on_progress("assign", 1.0, f"{n_weak} votes unsupported by their clusters' evidence")
        agreement = mask_agreement(label_map(clustering.labels, assignment.labels), evidence)
    a, trusted = trusted_settings(cfg.assign, agreement)
    cfg = replace(cfg, assign=a) if trusted else cfg
    if agreement == agreement:
        trust = "own evidence trusted" if trusted else "clusters decide"
        on_progress("assign", 1.0, f"mask agreement {agreement:.3f}: {trust}")
    refine = a.min_share_ratio > 0 and bool(labelled) and evidence is not None
    radius = adaptive_radius(means, a.contact_factor, seed=cfg.seed)
    stuff = stuff_ids(class_names, a.stuff_classes)
    if refine and evidence is not None:
        clustering, assignment = drop_inconsistent(
            evidence, clustering, assignment, (features, means, radius, stuff), a
        )
    ring_moves = 0
    if a.ring_plane_tol > 0 and bool(labelled):
        clustering, ring_moves = _release_rings(g, means, clustering, assignment, stuff, a)
        if ring_moves:
            on_progress("assign", 1.0, f"{ring_moves} Gaussians of support rings given back")
    semantic_ids = label_map(clustering.labels, assignment.labels)
    footprints = as_numpy(g.log_scales.max(dim=1).values.exp(), np.float64)
    background = None if total is None else total.unlabelled_share() > a.background_share
    instances, semantic_ids = build_objects(
        means, radius, evidence, clustering, assignment, semantic_ids, a, stuff, footprints,
        background,
    )  # fmt: skip
    left = 0 if background is None else int((background & (semantic_ids < 0)).sum())
    if left:
        on_progress("objects", 1.0, f"{left} Gaussians the class masks leave unlabelled stay so")
    on_progress("objects", 1.0, f"{instances.n_instances} objects from {k} clusters")
    if a.label_maps == "gaussians":
        maps, label_maps = final_maps(
            trained.views, clustering.labels if refine else None, maps, semantic_ids, cfg.masks,
            a.filter_label_maps, on_progress,
        )  # fmt: skip
    else:
        if refine:
            maps = cluster_maps(
                trained.views, clustering.labels, cfg.masks, on_progress, stage="refine"
            )
        label_maps = {
            name: label_map(ids, assignment.labels).astype(np.int32) for name, ids in maps.items()
        }
    return Segmentation(
        clustering, assignment, instances, semantic_ids, maps, label_maps, agreement, trusted,
        voted.unanimous, voted.confusions, ring_moves, left,
    )  # fmt: skip


def _release_rings(
    g: Gaussians,
    means: NDArray[np.float64],
    clustering: Clustering,
    assignment: Assignment,
    stuff: Sequence[int],
    cfg: AssignConfig,
) -> tuple[Clustering, int]:
    """``clustering`` with the support rings of objects given back to their supports
    (:mod:`dcseg.assign.rings`; the Gaussians' disc normals are their shortest axes), and
    how many Gaussians moved."""
    rotations = quat_to_rotmat(g.quats.detach())
    shortest = g.log_scales.detach().argmin(dim=1)
    rows = torch.arange(len(shortest), device=shortest.device)
    normals = as_numpy(rotations[rows, :, shortest], np.float64)
    labels, moved = release_rings(means, normals, clustering.labels, assignment.labels, stuff, cfg)
    return Clustering(labels, clustering.centers, clustering.scores), moved


def _report_consistency(assignment: Assignment, on_progress: Progress) -> None:
    """Say how much of the labelling rests on views that all agree, and what was undone."""
    if assignment.confusions:
        on_progress(
            "assign", 1.0,
            f"{assignment.confusions} clusters voted a look-alike class took the class their "
            "other views name (consistent confusion undone)",
        )  # fmt: skip
    if math.isfinite(assignment.unanimous):
        on_progress(
            "assign", 1.0,
            f"{100 * assignment.unanimous:.0f} % of labelled clusters are named alike in every "
            "matched view: where the segmenter is wrong about them, no vote can tell",
        )  # fmt: skip


def evaluate_segmentation(
    trained: TrainedScene,
    labels: Labels,
    semantic: Mapping[str, SemanticMap],
    gt: GroundTruth,
    vocabulary: Vocabulary,
    cfg: PipelineConfig,
) -> dict[str, Any]:
    """Metrics of the segmentation and of naive 2D fusion on the same ground-truth points.

    Returns:
        ``{"dcseg_projection": m, "dcseg_nearest": m, "naive_fusion": m, "instances": i,
        "summary": {...}}`` where each ``m`` is :func:`~dcseg.evaluate.stage.evaluate_scenes`
        output. Projection is the paper's protocol (label images, depth test); nearest
        transfers the labels of Gaussians above ``cfg.evaluate.min_opacity`` within
        ``cfg.evaluate.max_distance``; naive fusion votes the class-aware 2D maps directly,
        with no 3D reasoning. ``instances`` (:func:`~dcseg.evaluate.instances.instance_metrics`
        of the objects transferred like the nearest protocol) is there when the ground truth
        has instances and the labels carry them. A class-agnostic run (empty vocabulary) has
        the instance metrics only.
    """
    results: dict[str, Any] = {}
    if len(vocabulary):
        results = _semantic_metrics(trained, labels, semantic, gt, vocabulary, cfg)
    summary = {name: {"miou": m["miou"], "macc": m["macc"]} for name, m in results.items()}
    if gt.instances is not None and labels.instance_ids is not None:
        results["instances"] = _instance_metrics(trained, labels.instance_ids, gt, cfg)
        keys = ("f1", "precision", "recall", "mcov", "count_ratio")
        summary["instances"] = {k: results["instances"][k] for k in keys}
    return {**results, "summary": summary}


def _semantic_metrics(
    trained: TrainedScene,
    labels: Labels,
    semantic: Mapping[str, SemanticMap],
    gt: GroundTruth,
    vocabulary: Vocabulary,
    cfg: PipelineConfig,
) -> dict[str, Any]:
    views = trained.views
    n = len(vocabulary)
    tol = cfg.evaluate.depth_tol
    projection = vote_views(gt, views, [labels.label_maps[v.name] for v in views], n, tol)
    seen = [v for v in views if v.name in semantic]
    naive = vote_views(gt, seen, [semantic[v.name].classes for v in seen], n, tol)
    nearest = _nearest(trained, labels.semantic_ids, gt, cfg)
    return {
        name: evaluate_scenes([gt.labels], [pred], vocabulary.names, cfg.evaluate)
        for name, pred in (
            ("dcseg_projection", projection),
            ("dcseg_nearest", nearest),
            ("naive_fusion", naive),
        )
    }


def _instance_metrics(
    trained: TrainedScene, instance_ids: NDArray[np.int64], gt: GroundTruth, cfg: PipelineConfig
) -> dict[str, Any]:
    assert gt.instances is not None
    written = int(np.unique(instance_ids[instance_ids >= 0]).size)
    return instance_metrics(gt.instances, _nearest(trained, instance_ids, gt, cfg), written)


def _nearest(
    trained: TrainedScene, values: NDArray[np.int64], gt: GroundTruth, cfg: PipelineConfig
) -> NDArray[np.int64]:
    """Each ground-truth point takes the value of its nearest opaque Gaussian (3D protocol)."""
    g = trained.gaussians
    means = g.means.detach().cpu().numpy()
    return transfer_opaque(
        means, g.opacities().detach().cpu().numpy(), values, gt.points, cfg.evaluate
    )
