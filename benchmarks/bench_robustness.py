"""Segmentation quality over several reconstructions and clustering seeds (run by hand).

One synthetic scene per noise level (scene seed 0, as ``bench_segment.py``) is trained with
several pipeline seeds — each gives its own reconstruction, affinity features and clusters —
and every trained run is segmented again at several clustering seeds (no retraining). The
spread shows how much of a single-run score is luck; the mean is what the method is worth.

    python benchmarks/bench_robustness.py --out benchmarks/results/robustness.json
    python benchmarks/bench_robustness.py --noise heavy --pipeline-seeds 0 1 2 --cluster-seeds 0 10

Runs already in ``--work`` (``<noise>/run<seed>``) are reused, so a second call with other
segmentation defaults only re-scores (seconds per run).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from dcseg.config import JobConfig, PipelineConfig, preset  # noqa: E402
from dcseg.io.ground_truth import read_ground_truth  # noqa: E402
from dcseg.io.run_output import load_run  # noqa: E402
from dcseg.jobs import RunInputs, run_job  # noqa: E402
from dcseg.pipeline import evaluate_segmentation, segment_scene  # noqa: E402
from dcseg.synth import SynthConfig, generate_scene, write_scene  # noqa: E402


def ensure_run(work: Path, noise: str, seed: int, args: argparse.Namespace) -> Path:
    """The trained run of ``seed`` on the noise level's scene, trained now if missing."""
    scene = work / noise / "scene"
    if not (scene / "capture.json").is_file():
        width, height = args.size
        synth = SynthConfig(seed=0, frames=args.frames, width=width, height=height, noise=noise)
        write_scene(generate_scene(synth), scene)
    run = work / noise / f"run{seed}"
    if not (run / "run.json").is_file():
        start = time.perf_counter()
        run_job(RunInputs.from_bundle(scene), JobConfig(preset("fast").seeded(seed)), run)
        print(f"{noise} run{seed}: trained in {time.perf_counter() - start:.0f} s", flush=True)
    return run


def score_run(run: Path, scene: Path, cluster_seeds: list[int]) -> dict[str, Any]:
    """Projection mIoU of the current segmentation defaults at each clustering seed."""
    saved = load_run(run)
    now = preset("fast")
    cfg = PipelineConfig.from_dict(saved.record["config"])
    cfg = replace(cfg, cluster=now.cluster, masks=now.masks, assign=now.assign, scale=now.scale)
    gt = read_ground_truth(scene / "gt" / "points.ply", len(saved.vocabulary))
    scores, naive = [], 0.0
    for seed in cluster_seeds:
        c = replace(cfg, cluster=replace(cfg.cluster, seed=seed))
        seg = segment_scene(
            saved.trained,
            saved.semantic,
            len(saved.vocabulary),
            c,
            class_names=saved.vocabulary.names,
        )
        m = evaluate_segmentation(
            saved.trained, seg.labels(), saved.semantic, gt, saved.vocabulary, c
        )
        scores.append(round(100 * m["dcseg_projection"]["miou"], 2))
        naive = round(100 * m["naive_fusion"]["miou"], 2)
    return {"assignment_miou": scores, "naive_fusion_miou": naive}


def summary(rows: list[dict[str, Any]]) -> dict[str, float]:
    every = [s for r in rows for s in r["assignment_miou"]]
    naive = statistics.mean(r["naive_fusion_miou"] for r in rows)
    return {
        "mean": round(statistics.mean(every), 2),
        "min": min(every),
        "max": max(every),
        "naive_fusion": round(naive, 2),
        "mean_minus_naive": round(statistics.mean(every) - naive, 2),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/robustness.json"))
    parser.add_argument("--work", type=Path, default=Path("/tmp/dcseg-robustness"))
    parser.add_argument("--noise", nargs="+", default=["default", "heavy"])
    parser.add_argument("--pipeline-seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--cluster-seeds", nargs="+", type=int, default=[0, 10])
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument(
        "--size", type=lambda s: tuple(int(v) for v in s.split("x")), default=(320, 240)
    )
    args = parser.parse_args()
    results: dict[str, Any] = {}
    for noise in args.noise:
        rows = []
        for seed in args.pipeline_seeds:
            run = ensure_run(args.work, noise, seed, args)
            row = {
                "pipeline_seed": seed,
                **score_run(run, args.work / noise / "scene", args.cluster_seeds),
            }
            print(noise, json.dumps(row), flush=True)
            rows.append(row)
        results[noise] = {"runs": rows, "summary": summary(rows)}
        print(noise, json.dumps(results[noise]["summary"]), flush=True)
    meta = {
        "frames": args.frames,
        "size": list(args.size),
        "scene_seed": 0,
        "cluster_seeds": args.cluster_seeds,
        "preset": "fast",
        "date": time.strftime("%Y-%m-%d %H:%M"),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"meta": meta, "results": results}, indent=1) + "\n")


if __name__ == "__main__":
    main()
