"""Where a saved bench_segment run loses mIoU: per object and per class, three methods side by side.

For one trained run of ``bench_segment.py`` (``WORK/NOISE/layoutL``), re-segments the saved
state with the current defaults (one clustering seed) and compares, by the 3D protocol (naive
fusion: its projection), naive 2D fusion, the training-free 3D vote and dcseg:

* per ground-truth object: the class most of its points get under each method, and that
  class's share of the object's points (object-level decisions);
* per class present: IoU under each method (what the mean is made of);
* with ``--class NAME``: which ground-truth objects the points predicted ``NAME`` belong to
  (where a class's false positives come from, e.g. a table ring under a mug).

    python -m benchmarks.segment_breakdown --work WORK --noise detector --layout 8 --class mug
"""

from __future__ import annotations

import argparse
import tempfile
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from benchmarks.bench_segment import (
    Scorer,
    class_maps,
    current_config,
    exported_labels,
    run_dir,
    vote3d,
)
from dcseg.evaluate import EvaluateConfig, evaluate_scenes
from dcseg.io.ground_truth import read_ground_truth
from dcseg.io.run_output import SavedRun, load_run
from dcseg.pipeline import segment_scene
from dcseg.types import GroundTruth

Predictions = dict[str, NDArray[np.int64]]
"""Method name -> class per ground-truth point (-1 = none)."""


def predictions(saved: SavedRun, gt: GroundTruth, seed: int, sets: Sequence[str]) -> Predictions:
    """Naive fusion, the 3D vote and dcseg's labels on the ground-truth points."""
    cfg = current_config(saved, seed, sets)
    scorer = Scorer(saved, gt, cfg.evaluate.depth_tol)
    seen, maps = class_maps(saved)
    names = saved.vocabulary.names
    seg = segment_scene(saved.trained, saved.semantic, len(names), cfg, class_names=names)
    with tempfile.TemporaryDirectory() as tmp:
        labels = exported_labels(saved, seg, Path(tmp))
    return {
        "naive": scorer.projection(maps, seen),
        "vote3d": scorer.nearest(vote3d(saved, seen, maps)),
        "dcseg": scorer.nearest(labels.semantic_ids),
    }


def majority(values: NDArray[np.int64]) -> tuple[int, float]:
    """The most frequent non-negative value and its share of all ``values`` (-1, 0 if none)."""
    named = values[values >= 0]
    if not len(named):
        return -1, 0.0
    counts = np.bincount(named)
    return int(counts.argmax()), float(counts.max() / len(values))


def object_rows(gt: GroundTruth, preds: Predictions, names: Sequence[str]) -> list[str]:
    """One line per ground-truth object: its class, size and each method's majority class."""
    assert gt.instances is not None
    lines = []
    for inst in np.unique(gt.instances[gt.instances >= 0]):
        points = gt.instances == inst
        true, _ = majority(gt.labels[points])
        cells = []
        for pred in preds.values():
            cls, share = majority(pred[points])
            cells.append(f"{names[cls] if cls >= 0 else '-':>10} {share:4.2f}")
        line = f"{inst:>4} {names[true] if true >= 0 else '-':>10} {points.sum():>6} | "
        lines.append(line + " | ".join(cells))
    return lines


def class_rows(gt: GroundTruth, preds: Predictions, names: Sequence[str]) -> list[str]:
    """Per class present in the ground truth, its IoU (%) under each method, then the means."""
    cfg = EvaluateConfig()
    found = {k: evaluate_scenes([gt.labels], [p], names, cfg) for k, p in preds.items()}
    lines = [
        f"{name:>10} " + " ".join(f"{100 * m['iou'][name]:7.1f}" for m in found.values())
        for name in next(iter(found.values()))["present"]
    ]
    return [*lines, f"{'mIoU':>10} " + " ".join(f"{100 * m['miou']:7.1f}" for m in found.values())]


def sources(gt: GroundTruth, preds: Mapping[str, NDArray[np.int64]], cls: int) -> list[str]:
    """Per method, how many points of each ground-truth object are predicted ``cls``."""
    assert gt.instances is not None
    lines = []
    for method, pred in preds.items():
        hit = pred == cls
        ids, counts = np.unique(gt.instances[hit], return_counts=True)
        lines.append(
            f"{method:>7}: " + ", ".join(f"{i}: {c}" for i, c in zip(ids, counts, strict=True))
        )
    return lines


def main() -> None:
    p = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    p.add_argument("--work", type=Path, required=True)
    p.add_argument("--noise", required=True)
    p.add_argument("--layout", type=int, required=True)
    p.add_argument("--cluster-seed", type=int, default=0)
    p.add_argument("--class", dest="cls", help="where this class's predictions come from")
    p.add_argument("--set", nargs="*", default=[], metavar="KEY=JSON")
    args = p.parse_args()
    root = run_dir(args.work, args.noise, args.layout)
    saved = load_run(root / "run")
    names = saved.vocabulary.names
    gt = read_ground_truth(root / "scene" / "gt" / "points.ply", len(names))
    if gt.instances is None:
        raise SystemExit(f"{root / 'scene/gt/points.ply'}: no instance ids")
    preds = predictions(saved, gt, args.cluster_seed, args.set)
    header = " | ".join(f"{k:>15}" for k in preds)
    print(
        f"{'obj':>4} {'class':>10} {'points':>6} | {header}",
        *object_rows(gt, preds, names),
        sep="\n",
    )
    iou_header = f"{'class IoU':>10} " + " ".join(f"{k:>7}" for k in preds)
    print(iou_header, *class_rows(gt, preds, names), sep="\n")
    if args.cls:
        if args.cls not in names:
            raise SystemExit(f"--class {args.cls!r} is not in the vocabulary {list(names)}")
        print(f"points predicted {args.cls} by ground-truth object:")
        print(*sources(gt, preds, names.index(args.cls)), sep="\n")


if __name__ == "__main__":
    main()
