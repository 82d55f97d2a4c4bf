"""Objects with and without class masks on one trained run: instance metrics of both.

Re-segments a finished run twice from its trained state (nothing is retrained): with the run's
class-aware masks, and class-agnostically (no class masks), and scores both against the
scene's ground-truth instances (nearest-opaque-Gaussian transfer, IoU 0.5).

    python benchmarks/bench_class_agnostic.py RUN SCENE/gt/points.ply --out FILE.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from dcseg.io.ground_truth import read_ground_truth
from dcseg.io.run_output import load_run
from dcseg.jobs import stored_config
from dcseg.pipeline import evaluate_segmentation, segment_scene
from dcseg.types import Vocabulary


def score(run: Path, gt_file: Path) -> dict[str, Any]:
    saved, cfg = load_run(run), stored_config(run)
    rows: dict[str, Any] = {}
    for name, semantic, vocabulary in (
        ("classed", saved.semantic, saved.vocabulary),
        ("class_agnostic", {}, Vocabulary(())),
    ):
        seg = segment_scene(
            saved.trained, semantic, len(vocabulary), cfg, class_names=vocabulary.names
        )
        gt = read_ground_truth(gt_file, len(vocabulary))
        metrics = evaluate_segmentation(saved.trained, seg.labels(), semantic, gt, vocabulary, cfg)
        rows[name] = {"objects": seg.n_instances, **metrics["instances"]}
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path)
    parser.add_argument("gt", type=Path)
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    rows = {"run": str(args.run), **score(args.run, args.gt)}
    args.out.write_text(json.dumps(rows, indent=1) + "\n", encoding="utf-8")
    print(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
