"""Segmentation quality and cost on synthetic scenes: naive 2D fusion vs matching vs assignment.

For each noise level: synthesise a scene, run the pipeline once (fast preset), then segment the
saved state again with the other matcher (no retraining) and evaluate both, next to the naive
2D-fusion baseline on the same ground-truth points. Also times recluster and reclassify.

    python benchmarks/bench_segment.py --out benchmarks/results/segment.json
    python benchmarks/bench_segment.py --frames 24 --size 160x120   # a quicker variant
    python benchmarks/bench_segment.py --work /tmp/bench   # keep scenes and runs for inspection
    python benchmarks/bench_segment.py --work /tmp/bench --rescore   # re-segment the kept runs

``--rescore`` re-segments and re-evaluates the runs kept by an earlier ``--work`` run with the
current code and the current defaults of the segmentation stages (clustering, cluster masks,
assignment; the trained state is reused, nothing is retrained) and updates the scores in
``--out``; run, recluster and reclassify times stay as measured by that run.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from dcseg.config import PipelineConfig, preset  # noqa: E402
from dcseg.io.ground_truth import read_ground_truth  # noqa: E402
from dcseg.io.run_output import load_run  # noqa: E402
from dcseg.jobs import RunInputs, resegment_job, run_job  # noqa: E402
from dcseg.pipeline import evaluate_segmentation, segment_scene  # noqa: E402
from dcseg.synth import SynthConfig, generate_scene, write_scene  # noqa: E402


def bench_noise(noise: str, args: argparse.Namespace, work: Path) -> dict[str, Any]:
    scene = work / noise / "scene"
    width, height = args.size
    synth = SynthConfig(seed=args.seed, frames=args.frames, width=width, height=height, noise=noise)
    write_scene(generate_scene(synth), scene)
    inputs = RunInputs.from_bundle(scene)
    run = work / noise / "run"
    start = time.perf_counter()
    record = run_job(inputs, preset("fast").seeded(args.seed), run)
    run_seconds = time.perf_counter() - start
    table = matcher_table(run, scene)
    timings = derived_timings(run, scene, work / noise)
    return {
        "noise": noise,
        "run_seconds": round(run_seconds, 1),
        "stage_seconds": record["seconds"],
        "reconstruction": record["reconstruction"],
        "counts": record["counts"],
        "cache_mb": record["cache_mb"],
        **table,
        **timings,
    }


def matcher_table(run: Path, scene: Path, current_defaults: bool = False) -> dict[str, Any]:
    """Scores of both matchers on a saved run, with its own or the current segmentation config."""
    saved = load_run(run)
    cfg = PipelineConfig.from_dict(saved.record["config"])
    if current_defaults:
        now = preset("fast")
        cfg = replace(cfg, cluster=replace(now.cluster, seed=cfg.cluster.seed), masks=now.masks)
        cfg = replace(cfg, assign=now.assign, scale=now.scale)
    gt = read_ground_truth(scene / "gt" / "points.ply", len(saved.vocabulary))
    rows: dict[str, Any] = {}
    for mode in ("assignment", "matching"):
        c = replace(cfg, assign=replace(cfg.assign, mode=mode))
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
        rows[mode] = _scores(m["dcseg_projection"])
        rows[f"{mode}_nearest"] = _scores(m["dcseg_nearest"])
        rows["naive_fusion"] = _scores(m["naive_fusion"])
    return {"miou_macc": rows}


def derived_timings(run: Path, scene: Path, work: Path) -> dict[str, float]:
    start = time.perf_counter()
    resegment_job(run, work / "recluster", scale=0.5)
    mid = time.perf_counter()
    gt_maps, vocabulary = scene / "gt" / "semantic", scene / "vocabulary.txt"
    resegment_job(run, work / "reclassify", semantic_masks=gt_maps, vocabulary=vocabulary)
    end = time.perf_counter()
    return {"recluster_seconds": round(mid - start, 2), "reclassify_seconds": round(end - mid, 2)}


def _scores(metrics: dict[str, Any]) -> dict[str, float]:
    return {"miou": round(100 * metrics["miou"], 2), "macc": round(100 * metrics["macc"], 2)}


def markdown(results: list[dict[str, Any]]) -> str:
    lines = [
        "| noise | naive fusion mIoU/mAcc | matching | assignment | run s | peak MB |",
        "|---|---|---|---|---|---|",
    ]
    for r in results:
        t = r["miou_macc"]
        cells = [
            f"{t[k]['miou']:.1f} / {t[k]['macc']:.1f}"
            for k in ("naive_fusion", "matching", "assignment")
        ]
        lines.append(
            f"| {r['noise']} | {' | '.join(cells)} | {r['run_seconds']:.0f} | {r['peak_mb']:.0f} |"
        )
    return "\n".join(lines)


def rescore(args: argparse.Namespace) -> None:
    """Update ``args.out`` with scores and re-segmentation times of the runs in ``args.work``."""
    if args.work is None:
        raise SystemExit("--rescore needs --work (the folder of an earlier --work run)")
    data = json.loads(args.out.read_text())
    for result in data["results"]:
        noise = result["noise"]
        run, scene = args.work / noise / "run", args.work / noise / "scene"
        result.update(matcher_table(run, scene, current_defaults=True))
        result["rescored"] = time.strftime("%Y-%m-%d %H:%M")
        print(json.dumps(result["miou_macc"]), flush=True)
    args.out.write_text(json.dumps(data, indent=1) + "\n")
    print(markdown(data["results"]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/segment.json"))
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument(
        "--size", type=lambda s: tuple(int(v) for v in s.split("x")), default=(320, 240)
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--noise", nargs="+", default=["clean", "default", "heavy"])
    parser.add_argument(
        "--work", type=Path, default=None, help="keep scenes and runs here (default: a temp dir)"
    )
    parser.add_argument(
        "--rescore", action="store_true", help="re-segment the runs kept in --work (no training)"
    )
    args = parser.parse_args()
    if args.rescore:
        rescore(args)
        return
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        work = args.work if args.work is not None else Path(tmp)
        for noise in args.noise:
            result = bench_noise(noise, args, work)
            result["peak_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
            results.append(result)
            print(json.dumps(result["miou_macc"]), flush=True)
    meta = {"frames": args.frames, "size": list(args.size), "seed": args.seed, "preset": "fast"}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"meta": meta, "results": results}, indent=1) + "\n")
    print(markdown(results))


if __name__ == "__main__":
    main()
