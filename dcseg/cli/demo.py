"""``dcseg demo``: synthesise a scene and run the whole pipeline on it, with evaluation."""

from __future__ import annotations

import argparse
import json
import logging
import shutil
import sys
from pathlib import Path
from typing import Any

from dcseg.cli._options import parse_size
from dcseg.cli._pipeline import add_device_option

log = logging.getLogger("dcseg")


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "demo",
        help="synthesise a scene and segment it end to end",
        description="Generate a synthetic room (pybullet) with simulated SAM-style and "
        "open-vocabulary masks into OUT/scene, run the pipeline into OUT/run, and print the "
        "metrics against the scene's ground truth next to the naive 2D-fusion baseline.",
    )
    parser.add_argument("--out", type=Path, default=Path("runs/demo"), help="(runs/demo)")
    parser.add_argument("--frames", type=int, default=16, help="synthetic views (16)")
    parser.add_argument(
        "--size", type=parse_size, default=(160, 120), help="view size WxH (160x120)"
    )
    parser.add_argument("--seed", type=int, default=0, help="scene and method seed (0)")
    parser.add_argument("--preset", choices=("fast", "paper"), default="fast", help="(fast)")
    parser.add_argument("--quiet", action="store_true", help="no progress bars")
    add_device_option(parser)
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from dcseg.cli._options import build
    from dcseg.cli._progress import StageBars
    from dcseg.jobs import RunInputs, run_job
    from dcseg.synth import SynthConfig, generate_scene, write_scene

    scene_dir, run_dir = args.out / "scene", args.out / "run"
    if scene_dir.exists():
        shutil.rmtree(scene_dir)
    log.info("synthesising %d views into %s", args.frames, scene_dir)
    width, height = args.size
    synth = SynthConfig(seed=args.seed, frames=args.frames, width=width, height=height)
    write_scene(generate_scene(synth), scene_dir)
    inputs = RunInputs.from_bundle(scene_dir)
    with StageBars(enabled=not args.quiet) as bars:
        config = build(args.preset, {"segment": {"seed": args.seed}})
        record = run_job(inputs, config, run_dir, bars, device=args.device)
    sys.stdout.write(json.dumps({"out": str(run_dir), **_summary(record)}, indent=1) + "\n")
    return 0


def _summary(record: dict[str, Any]) -> dict[str, Any]:
    return {
        "instances": record["counts"]["clusters"],
        "labelled_instances": record["counts"]["labelled_clusters"],
        "seconds": record["seconds"],
        "mIoU": {
            k: round(v["miou"], 4) for k, v in record["metrics_summary"].items() if "miou" in v
        },
        "instance_metrics": record["metrics_summary"].get("instances"),
    }
