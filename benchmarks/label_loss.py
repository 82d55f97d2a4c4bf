"""Where the 3D labels are lost, per ground-truth instance: clustering, assignment or transfer.

    python -m benchmarks.label_loss WORK/heavy/layout4 [--seeds 0 10] [--out FILE]

Each opaque Gaussian (opacity > 0.05) is given the instance of its nearest ground-truth point
(within 5 cm, else none). The run is segmented like :mod:`benchmarks.bench_segment` (current
defaults, ``--set`` overrides), and every ground-truth point of the 3D protocol falls in one
class: ``correct``; ``none`` (no opaque Gaussian within 5 cm); ``transfer`` (wrong, and the
nearest Gaussian belongs to another object); else wrong on a Gaussian of its own object whose
final cluster is ``noise`` (-1), ``merged`` (a cluster most of whose Gaussians are another
object's) or its own (``assignment``: the cluster's class is wrong or none). Per instance also:
opaque Gaussians, first-pass (HDBSCAN) noise share, the first-pass cluster holding most of them
(its share of the object and its purity) and the cosine of the object's mean gated feature to
its own Gaussians (within) and to the closest other object's mean (between).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from benchmarks.bench_segment import current_config
from dcseg.affinity.data import gated_features
from dcseg.cluster.stage import cluster_features
from dcseg.evaluate import EvaluateConfig, evaluate_scenes, transfer_opaque
from dcseg.io.ground_truth import read_ground_truth
from dcseg.io.run_output import load_run
from dcseg.pipeline import segment_scene
from dcseg.types import GroundTruth

OPAQUE, RADIUS = 0.05, 0.05
PROTOCOL = EvaluateConfig()
KINDS = ("correct", "none", "transfer", "noise", "merged", "assignment")

Ints = NDArray[np.int64]


def owners(means: NDArray[Any], gt: GroundTruth) -> Ints:
    """Instance of the nearest ground-truth point of every Gaussian, -1 beyond 5 cm."""
    assert gt.instances is not None
    dist, idx = cKDTree(gt.points).query(means)
    return np.where(dist <= RADIUS, gt.instances[idx], -1).astype(np.int64)


def majority(clusters: Ints, owner: Ints, k: int) -> Ints:
    """The instance most of each cluster's Gaussians belong to (-1 = none)."""
    out = np.full(k, -1, dtype=np.int64)
    for c in range(k):
        ids = owner[(clusters == c) & (owner >= 0)]
        if ids.size:
            out[c] = np.bincount(ids).argmax()
    return out


def point_kinds(
    gt: GroundTruth, means: NDArray[Any], owner: Ints, labels: Ints, clusters: Ints,
    cluster_owner: Ints,
) -> NDArray[np.str_]:  # fmt: skip
    """The category (:data:`KINDS`) of every ground-truth point under the 3D protocol."""
    assert gt.instances is not None
    dist, near = cKDTree(means).query(gt.points)
    kinds = np.full(len(gt.points), "correct", dtype="<U10")
    wrong = labels[near] != gt.labels
    c = clusters[near]
    foreign = owner[near] != gt.instances
    kinds[wrong & (c >= 0)] = "assignment"
    merged = wrong & (c >= 0) & (cluster_owner[np.maximum(c, 0)] != gt.instances)
    kinds[merged] = "merged"
    kinds[wrong & (c < 0)] = "noise"
    kinds[wrong & foreign] = "transfer"
    kinds[dist > RADIUS] = "none"
    kinds[gt.labels < 0] = "ignored"
    return kinds


def feature_stats(feats: NDArray[Any], owner: Ints, inst: int) -> dict[str, float]:
    """Cosine of an object's mean feature to its own Gaussians and to the closest other object."""
    mine = feats[owner == inst]
    if not len(mine):
        return {}
    mean = mine.mean(0) / np.linalg.norm(mine.mean(0))
    others = [j for j in np.unique(owner) if j >= 0 and j != inst]
    between = [
        (float(mean @ (m := feats[owner == j].mean(0)) / np.linalg.norm(m)), j) for j in others
    ]
    best = max(between) if between else (float("nan"), -1)
    return {"within": float((mine @ mean).mean()), "between": best[0], "closest": int(best[1])}


def instance_rows(
    gt: GroundTruth, kinds: NDArray[np.str_], owner: Ints, first: Ints, feats: NDArray[Any],
    names: list[str],
) -> list[dict[str, Any]]:  # fmt: skip
    assert gt.instances is not None
    rows = []
    for inst in np.unique(gt.instances[gt.instances >= 0]):
        pts = gt.instances == inst
        cls = int(np.bincount(gt.labels[pts][gt.labels[pts] >= 0]).argmax())
        mine = first[owner == inst]
        row: dict[str, Any] = {"instance": int(inst), "class": names[cls], "points": int(pts.sum())}
        row["gaussians"] = int(mine.size)
        row["first_noise"] = round(float((mine < 0).mean()), 3) if mine.size else None
        if (mine >= 0).any():
            best = int(np.bincount(mine[mine >= 0]).argmax())
            in_best = owner[first == best]
            row["first_cluster_share"] = round(float((mine == best).mean()), 3)
            row["first_cluster_purity"] = round(float((in_best == inst).mean()), 3)
        row["points_by_kind"] = {k: round(float((kinds[pts] == k).mean()), 3) for k in KINDS}
        row["features"] = {k: round(v, 3) for k, v in feature_stats(feats, owner, inst).items()}
        rows.append(row)
    return rows


def diagnose(root: Path, seed: int, overrides: list[str]) -> dict[str, Any]:
    saved = load_run(root / "run")
    names = list(saved.vocabulary.names)
    gt = read_ground_truth(root / "scene" / "gt" / "points.ply", len(names))
    cfg = current_config(saved, seed, overrides)
    g = saved.trained.gaussians
    opaque = g.opacities().detach().cpu().numpy().reshape(-1) > OPAQUE
    means = g.means.detach().cpu().numpy()
    feats_t = gated_features(saved.trained.affinity, cfg.scale)
    first = cluster_features(feats_t, g.means, g.opacities(), cfg.cluster).labels
    seg = segment_scene(saved.trained, saved.semantic, len(names), cfg, class_names=names)
    owner = owners(means, gt)
    clusters = np.asarray(seg.clustering.labels)
    cluster_owner = majority(clusters[opaque], owner[opaque], seg.n_clusters)
    labels = np.asarray(seg.semantic_ids)
    kinds = point_kinds(
        gt, means[opaque], owner[opaque], labels[opaque], clusters[opaque], cluster_owner
    )
    feats = feats_t.cpu().numpy()[opaque]
    rows = instance_rows(gt, kinds, owner[opaque], np.asarray(first)[opaque], feats, names)
    scored = kinds[kinds != "ignored"]
    total = {k: round(float((scored == k).mean()), 4) for k in KINDS}
    pred = transfer_opaque(means, g.opacities().detach().cpu().numpy(), labels, gt.points, PROTOCOL)
    m = evaluate_scenes([gt.labels], [pred], names, PROTOCOL)
    iou = {n: round(100 * v, 1) for n, v in m["iou"].items() if v == v}
    return {
        "seed": seed, "clusters": seg.n_clusters, "miou": round(100 * m["miou"], 2), "iou": iou,
        "points_by_kind": total, "instances": rows,
    }  # fmt: skip


def table(result: dict[str, Any]) -> str:
    head = "inst class gaussians noise1 share1 purity1 " + " ".join(KINDS[1:]) + " within between"
    lines = [
        f"seed {result['seed']}: {result['clusters']} clusters, mIoU {result['miou']}",
        f"{result['iou']}",
        f"{result['points_by_kind']}",
        head,
    ]
    for r in result["instances"]:
        k, f = r["points_by_kind"], r["features"]
        cells = [r["instance"], r["class"], r["gaussians"], r.get("first_noise"),
                 r.get("first_cluster_share"), r.get("first_cluster_purity"),
                 *(k[n] for n in KINDS[1:]), f.get("within"), f.get("between")]  # fmt: skip
        lines.append(" ".join(str(c) for c in cells))
    return "\n".join(lines)


def main() -> None:
    p = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    p.add_argument("root", type=Path, help="WORK/NOISE/layoutN of bench_segment")
    p.add_argument("--seeds", nargs="+", type=int, default=[0, 10])
    p.add_argument("--set", nargs="*", default=[], metavar="KEY=JSON")
    p.add_argument("--out", type=Path)
    args = p.parse_args()
    results = [diagnose(args.root, s, args.set) for s in args.seeds]
    for r in results:
        print(table(r))
    if args.out:
        args.out.write_text(json.dumps({"root": str(args.root), "runs": results}, indent=1) + "\n")


if __name__ == "__main__":
    main()
