"""Per labelled cluster, what the confusion step sees and what the ground truth says.

For each trained run of ``bench_segment.py`` (``--work W --noise N --layouts L``) and
clustering seed: cluster the saved state with the current defaults, render the cluster maps,
match them to the class maps as the assignment stage does, and write one row per labelled
cluster: its voted class, its companion (the other class matched in most views), the views
matched to each, the other wrong names (count, classes, entropy), the mean matched IoU of
the voted class and of the companion, whether the companion class has lone clusters
elsewhere in the scene, how many clusters of the voted class share that companion, and the
ground-truth majority class of the points nearest to its Gaussians (the 3D protocol).

    python -m benchmarks.confusion_gate_stats --work W --noise heavy --layouts 4 --out F.jsonl

Used to choose the gate of :mod:`dcseg.assign.confusion` (``results/confusion_gate.json``).
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.bench_segment import PROTOCOL, current_config, run_dir
from dcseg.affinity import gated_features
from dcseg.assign.confusion import companions, view_counts
from dcseg.assign.stage import _matches_per_view
from dcseg.assign.vote import decide, tally
from dcseg.cluster.stage import cluster_features
from dcseg.evaluate.points import transfer_opaque
from dcseg.io.ground_truth import read_ground_truth
from dcseg.io.run_output import load_run
from dcseg.progress import quiet
from dcseg.segment.views import cluster_maps


def cluster_rows(work: Path, noise: str, layout: int, seed: int) -> list[dict[str, Any]]:
    root = run_dir(work, noise, layout)
    saved = load_run(root / "run")
    names = saved.vocabulary.names
    gt = read_ground_truth(root / "scene" / "gt" / "points.ply", len(names))
    cfg = current_config(saved, seed)
    trained = saved.trained
    g = trained.gaussians
    clustering = cluster_features(
        gated_features(trained.affinity, cfg.scale), g.means, g.opacities(), cfg.cluster
    )
    k, c = int(clustering.centers.shape[0]), len(names)
    labelled = [v.name for v in trained.views if v.name in saved.semantic]
    maps = cluster_maps(trained.views, clustering.labels, cfg.masks, quiet)
    views = list(
        _matches_per_view(
            [maps[n] for n in labelled],
            [saved.semantic[n].classes for n in labelled],
            k,
            c,
            cfg.assign,
        )
    )
    votes, _ = tally(views, k, c)
    labels, _ = decide(votes)
    counts = view_counts(views, k, c)
    a = cfg.assign
    share = 0.15
    comp = companions(
        labels, counts, votes, share, a.confusion_min_views, a.confusion_min_iou_ratio
    )
    tested = (labels >= 0) & (counts.sum(axis=1) >= math.ceil(a.confusion_min_views / share))
    lone = np.bincount(labels[tested & (comp < 0)], minlength=c)
    voted = np.bincount(labels[tested], minlength=c)
    # ground truth: points -> nearest opaque Gaussian's cluster -> majority class per cluster
    opac = g.opacities().detach().cpu().numpy()
    means = g.means.detach().cpu().numpy()
    point_cluster = transfer_opaque(means, opac, np.asarray(clustering.labels), gt.points, PROTOCOL)
    rows = []
    iou = np.divide(votes, counts, out=np.zeros_like(votes), where=counts > 0)
    for j in np.flatnonzero(labels >= 0):
        y = int(labels[j])
        n = counts[j]
        others = n.astype(float).copy()
        others[y] = 0
        x = int(others.argmax())
        rest = others.copy()
        rest[x] = 0
        wrong = others[others > 0]
        p = wrong / wrong.sum() if wrong.sum() else wrong
        ent = float(-(p * np.log(p)).sum()) if len(p) else 0.0
        pts = gt.labels[(point_cluster == j) & (gt.labels >= 0)]
        gt_cls = int(np.bincount(pts, minlength=c).argmax()) if len(pts) else -1
        gt_share = float(np.mean(pts == gt_cls)) if len(pts) else 0.0
        same_comp = int(((labels == y) & tested & (comp == comp[j])).sum()) if comp[j] >= 0 else 0
        rows.append(
            {
                "noise": noise,
                "layout": layout,
                "seed": seed,
                "cluster": int(j),
                "n_gauss": int((clustering.labels == j).sum()),
                "n_points": len(pts),
                "y": names[y],
                "x": names[x] if others[x] > 0 else None,
                "gt": names[gt_cls] if gt_cls >= 0 else None,
                "gt_share": round(gt_share, 3),
                "views": int(n.sum()),
                "own": int(n[y]),
                "comp_views": int(others[x]),
                "rest_views": int(rest.sum()),
                "n_wrong_classes": int((others > 0).sum()),
                "wrong_entropy": round(ent, 3),
                "own_iou": round(float(iou[j, y]), 3),
                "comp_iou": round(float(iou[j, x]), 3),
                "companion": names[int(comp[j])] if comp[j] >= 0 else None,
                "tested": bool(tested[j]),
                "y_voted": int(voted[y]),
                "y_lone": int(lone[y]),
                "x_voted": int(voted[x]),
                "x_lone": int(lone[x]),
                "y_same_companion": same_comp,
                "x_companion_of_x_clusters": [
                    names[int(v)] if v >= 0 else None for v in comp[(labels == x) & tested]
                ],
            }
        )
    return rows


def main() -> None:
    p = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    p.add_argument("--work", type=Path, required=True)
    p.add_argument("--noise", required=True)
    p.add_argument("--layouts", nargs="+", type=int, required=True)
    p.add_argument("--cluster-seeds", nargs="+", type=int, default=[0, 10])
    p.add_argument("--out", type=Path, required=True)
    args = p.parse_args()
    with args.out.open("a") as f:
        for layout in args.layouts:
            for seed in args.cluster_seeds:
                for row in cluster_rows(args.work, args.noise, layout, seed):
                    f.write(json.dumps(row) + "\n")
                print(f"{args.noise} layout{layout} seed{seed} done", flush=True)


if __name__ == "__main__":
    main()
