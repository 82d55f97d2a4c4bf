"""Benchmark cost against capture size: time and peak memory per stage of ``run_job``.

Usage::

    python benchmarks/bench_scale.py --frames 20 60 --sizes 160x120 --work /tmp/scale
    python benchmarks/bench_scale.py --frames 40 200 --sizes 320x240 640x480 \\
        --out benchmarks/results/scale.json
    python benchmarks/superpixel_bundle.py ../shared/data/replica_room0_small /tmp/replica
    python benchmarks/bench_scale.py --bundle /tmp/replica --out replica.json

For every frames x size pair: ``dcseg synth`` writes a scene into ``--work`` (kept, so a
second call reuses it), then a child process runs :func:`dcseg.jobs.run_job` on it with the
chosen preset and optional step overrides (``--reconstruct-iterations``,
``--affinity-iterations``: a scale study at fewer steps still shows how memory grows with
frames and pixels) and frame budget (``--max-side``, ``--keyframes``; the fast preset trains
at most 200 keyframes, so a study of growth in frames passes ``--keyframes all``). Each row
has the child's wall and CPU seconds, its peak RSS, the peak by the end of each phase
(``run.json``: read, reconstruct, train, segment, evaluate, write), the per-phase seconds,
the cache's size on disk and ``state/`` per frame. Rows are written to ``--out`` as they
finish. ``--bundle PATH`` (repeatable) measures existing bundles instead of synthetic scenes,
e.g. a real capture with stand-in masks from ``benchmarks/superpixel_bundle.py``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import time
from pathlib import Path
from typing import Any


def parse_size(text: str) -> tuple[int, int]:
    width, height = (int(v) for v in text.lower().split("x"))
    return width, height


def synth(scene: Path, frames: int, size: tuple[int, int]) -> None:
    if (scene / "vocabulary.txt").is_file():
        return
    args = ["synth", str(scene), "--frames", str(frames), "--size", f"{size[0]}x{size[1]}"]
    subprocess.run([sys.executable, "-m", "dcseg", *args], check=True)


def child(args: argparse.Namespace) -> int:
    """Run one job in this process (the parent measures it)."""
    from dcseg.jobs import RunInputs, run_job
    from dcseg.options import build_config, parse_options

    options: dict[str, Any] = {"reconstruct": {}, "affinity": {}, "budget": {}}
    if args.reconstruct_iterations is not None:
        options["reconstruct"]["iterations"] = args.reconstruct_iterations
    if args.affinity_iterations is not None:
        options["affinity"]["iterations"] = args.affinity_iterations
    for name, value in (("max_side", args.max_side), ("max_keyframes", args.keyframes)):
        if value is not None:
            options["budget"][name] = int(value) if value.isdigit() else value
    config = build_config(args.preset, parse_options(options))
    run_job(RunInputs.from_bundle(Path(args.scene)), config, Path(args.run), device=args.device)
    return 0


def measure(scene: Path, run: Path, args: argparse.Namespace) -> dict[str, Any]:
    command = [sys.executable, __file__, "--child", "--scene", str(scene), "--run", str(run)]
    command += ["--preset", args.preset, "--device", args.device]
    for flag in ("reconstruct_iterations", "affinity_iterations", "max_side", "keyframes"):
        value = getattr(args, flag)
        if value is not None:
            command += [f"--{flag.replace('_', '-')}", str(value)]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    subprocess.run(command, check=True)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    record = json.loads((run / "run.json").read_text(encoding="utf-8"))
    state = sum(p.stat().st_size for p in (run / "state").rglob("*") if p.is_file())
    frames = record["counts"]["views"]
    return {
        "views": frames,
        "train_size": record.get("capture", {}).get("size"),
        "wall_seconds": round(wall, 1),
        "cpu_seconds": round(
            after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime, 1
        ),
        "peak_memory_mb": record["peak_memory_mb"],
        "peak_memory_mb_by_phase": record.get("peak_memory_mb_by_phase"),
        "seconds": record["seconds"],
        "gaussians": record["counts"]["gaussians"],
        "cache_mb": record["cache_mb"],
        "state_mb": round(state / 2**20, 1),
        "state_mb_per_frame": round(state / 2**20 / frames, 2),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--frames", type=int, nargs="+", default=[20, 60])
    parser.add_argument("--sizes", type=parse_size, nargs="+", default=[(160, 120)])
    parser.add_argument("--preset", default="fast")
    parser.add_argument("--device", default="auto")
    parser.add_argument("--reconstruct-iterations", type=int)
    parser.add_argument("--affinity-iterations", type=int)
    parser.add_argument("--max-side", help="frame budget: N or native (default: the preset's)")
    parser.add_argument("--keyframes", help="frame budget: N or all (default: the preset's)")
    parser.add_argument("--bundle", type=Path, action="append", default=[])
    parser.add_argument("--work", type=Path, default=Path("/tmp/dcseg-scale"))
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/scale.json"))
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--scene", help=argparse.SUPPRESS)
    parser.add_argument("--run", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        return child(args)
    rows: list[dict[str, Any]] = []
    for bundle in args.bundle:
        row = {"bundle": str(bundle), **measure(bundle, args.work / f"run-{bundle.name}", args)}
        rows.append(row)
        print(json.dumps(row))
        write(args, rows)
    if args.bundle:
        return 0
    for width, height in args.sizes:
        for frames in args.frames:
            scene = args.work / f"scene-{frames}-{width}x{height}"
            synth(scene, frames, (width, height))
            run = args.work / f"run-{frames}-{width}x{height}"
            row = {"frames": frames, "size": f"{width}x{height}", **measure(scene, run, args)}
            rows.append(row)
            print(json.dumps(row))
            write(args, rows)
    return 0


def write(args: argparse.Namespace, rows: list[dict[str, Any]]) -> None:
    body = {
        "preset": args.preset,
        "overrides": {
            "reconstruct.iterations": args.reconstruct_iterations,
            "affinity.iterations": args.affinity_iterations,
            "budget.max_side": args.max_side,
            "budget.max_keyframes": args.keyframes,
        },
        "machine": {"cpus": len(os.sched_getaffinity(0)), "python": platform.python_version()},
        "rows": rows,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(body, indent=2) + "\n", encoding="utf-8")


if __name__ == "__main__":
    sys.exit(main())
