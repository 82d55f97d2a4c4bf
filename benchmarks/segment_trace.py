"""Trace one ground-truth object of a saved bench_segment run through the segmentation.

For ``WORK/NOISE/layoutL`` and one object id of ``scene/gt/points.ply``, re-segments the saved
state with the current defaults (one clustering seed) and prints:

* the Gaussians that stand for the object: the nearest opaque one of each of its points;
* every first cluster they lie in (before the consistency step): how many of them, its size,
  its vote (class, views matched, the top summed IoU votes), the pooled evidence of the
  object's part of it, and the ground-truth objects the whole cluster lies on;
* the clusters and classes they end in.

Where a small object is lost: merged into its support's cluster, split into fragments that
vote apart, or moved away by a later step (compare with ``--set assign.ring_plane_tol=0``).

    python -m benchmarks.segment_trace --work WORK --noise heavy --layout 13 --object 17
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from benchmarks.bench_segment import PROTOCOL, current_config, run_dir
from dcseg.affinity import gated_features
from dcseg.assign.stage import Assignment, assign_labels
from dcseg.cluster.features import Clustering, as_numpy
from dcseg.cluster.stage import cluster_features
from dcseg.config import PipelineConfig
from dcseg.evaluate.points import transfer_opaque
from dcseg.io.ground_truth import read_ground_truth
from dcseg.io.run_output import SavedRun, load_run
from dcseg.pipeline import segment_scene
from dcseg.progress import quiet
from dcseg.segment import EvidenceSum
from dcseg.segment.views import cluster_maps
from dcseg.types import GroundTruth


def object_gaussians(
    means: NDArray[np.float64], opacities: NDArray[np.float64], points: NDArray[np.float64]
) -> NDArray[np.int64]:
    """Sorted unique indices of the Gaussians that stand for ``points`` under the 3D
    protocol (:func:`dcseg.evaluate.points.transfer_opaque`: the nearest opaque one)."""
    index = transfer_opaque(means, opacities, np.arange(len(means)), points, PROTOCOL)
    return np.unique(index[index >= 0]).astype(np.int64)


def makeup(
    gt_instances: NDArray[np.int64], tree: cKDTree, centres: NDArray[np.float64]
) -> list[tuple[int, int]]:
    """Ground-truth objects that ``centres`` lie on (nearest point within the 3D protocol's
    ``max_distance``), as ``(object id, count)``, most first; -1 = no object."""
    if not len(centres):
        return []
    gap, index = tree.query(centres)
    reach = gap < PROTOCOL.max_distance
    ids, counts = np.unique(gt_instances[index[reach]], return_counts=True)
    order = np.argsort(-counts, kind="stable")
    return [(int(ids[i]), int(counts[i])) for i in order]


def top(values: NDArray[np.float64], names: Sequence[str], n: int = 3) -> str:
    """The ``n`` largest positive ``values`` as ``"name value"``, comma-separated."""
    order = np.argsort(-values, kind="stable")[:n]
    return ", ".join(f"{names[c]} {values[c]:.2f}" for c in order if values[c] > 0)


def cluster_line(
    c: int, here: int, size: int, a: Assignment, pooled_part: NDArray[np.float64],
    objects: list[tuple[int, int]], names: Sequence[str],
) -> str:  # fmt: skip
    """One first cluster: the object's Gaussians in it, its size, vote, evidence, make-up."""
    voted = names[a.labels[c]] if a.labels[c] >= 0 else "-"
    parts = ", ".join(f"{o}: {n}" for o, n in objects[:4])
    return (
        f"cluster {c}: {here} of the object's / {size}; voted {voted} in {a.n_views[c]} views "
        f"({top(a.votes[c], names)}) | evidence of the object's part: {top(pooled_part, names)}"
        f" | lies on objects {parts}"
    )


def first_vote(
    saved: SavedRun, cfg: PipelineConfig
) -> tuple[Clustering, Assignment, NDArray[np.float64]]:
    """The first clustering, its vote and every Gaussian's class evidence, as
    :func:`dcseg.pipeline.segment_scene` makes them before the consistency step."""
    trained, semantic = saved.trained, saved.semantic
    g, n_classes = trained.gaussians, len(saved.vocabulary.names)
    clustering = cluster_features(
        gated_features(trained.affinity, cfg.scale), g.means, g.opacities(), cfg.cluster
    )
    total = EvidenceSum(len(g.means), n_classes)
    maps = cluster_maps(trained.views, clustering.labels, cfg.masks, quiet, total, semantic)
    named = [v.name for v in trained.views if v.name in semantic]
    k = int(clustering.centers.shape[0])
    vote = assign_labels([maps[n] for n in named], [semantic[n].classes for n in named], k,
                         n_classes, cfg.assign)  # fmt: skip
    return clustering, vote, total.evidence


def trace(saved: SavedRun, gt: GroundTruth, obj: int, cfg: PipelineConfig) -> list[str]:
    """The lines :func:`main` prints for ground-truth object ``obj``."""
    assert gt.instances is not None
    names = saved.vocabulary.names
    g = saved.trained.gaussians
    means = as_numpy(g.means, np.float64)
    mine = object_gaussians(means, as_numpy(g.opacities(), np.float64).ravel(),
                            gt.points[gt.instances == obj])  # fmt: skip
    lines = [f"object {obj}: {int((gt.instances == obj).sum())} points, {len(mine)} Gaussians"]
    clustering, vote, evidence = first_vote(saved, cfg)
    tree = cKDTree(gt.points)
    first = clustering.labels[mine]
    for c in (int(c) for c in np.unique(first)):
        part = mine[first == c]
        if c < 0:
            lines.append(f"noise: {len(part)} of the object's")
            continue
        whole = np.flatnonzero(clustering.labels == c)
        pooled = np.asarray(evidence[part], dtype=np.float64).sum(axis=0)
        objects = makeup(gt.instances, tree, means[whole])
        lines.append(cluster_line(c, len(part), len(whole), vote, pooled, objects, names))
    seg = segment_scene(saved.trained, saved.semantic, len(names), cfg, class_names=names)
    ends = seg.clustering.labels[mine]
    for c in (int(c) for c in np.unique(ends)):
        cls = names[seg.assignment.labels[c]] if c >= 0 and seg.assignment.labels[c] >= 0 else "-"
        size = int((seg.clustering.labels == c).sum()) if c >= 0 else 0
        lines.append(f"ends in cluster {c} ({cls}, {size} Gaussians): {(ends == c).sum()}")
    final = seg.semantic_ids[mine]
    classes = ", ".join(
        f"{names[c] if c >= 0 else '-'} {(final == c).sum()}" for c in np.unique(final)
    )
    return [*lines, f"final classes: {classes}"]


def main() -> None:
    p = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    p.add_argument("--work", type=Path, required=True)
    p.add_argument("--noise", required=True)
    p.add_argument("--layout", type=int, required=True)
    p.add_argument("--object", type=int, required=True, help="ground-truth instance id")
    p.add_argument("--cluster-seed", type=int, default=0)
    p.add_argument("--set", nargs="*", default=[], metavar="KEY=JSON")
    args = p.parse_args()
    root = run_dir(args.work, args.noise, args.layout)
    saved = load_run(root / "run")
    gt = read_ground_truth(root / "scene" / "gt" / "points.ply", len(saved.vocabulary.names))
    if gt.instances is None or not (gt.instances == args.object).any():
        raise SystemExit(f"{root / 'scene/gt/points.ply'}: no points of object {args.object}")
    cfg = current_config(saved, args.cluster_seed, args.set)
    print(*trace(saved, gt, args.object, cfg), sep="\n")


if __name__ == "__main__":
    main()
