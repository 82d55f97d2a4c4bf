"""``dcseg recluster``: cluster a finished run at another scale, without retraining."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from dcseg.cli._pipeline import add_output_options, run_reporting


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "recluster",
        help="re-cluster a run at another scale (no retraining)",
        description="Cluster the trained features of RUN at scale S and write a complete new "
        "output to OUT; reconstruction and feature training are reused, not repeated.",
    )
    parser.add_argument("run_dir", type=Path, metavar="RUN", help="a finished run folder")
    parser.add_argument("--scale", type=float, required=True, help="scale in [0, 1]")
    parser.add_argument("--out", type=Path, required=True, help="output folder")
    add_output_options(parser)
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from dcseg.jobs import resegment_job

    if not 0.0 <= args.scale <= 1.0:
        raise SystemExit(f"dcseg: --scale must be in [0, 1], got {args.scale}")

    def job(progress: Any) -> dict[str, Any]:
        return resegment_job(args.run_dir, args.out, scale=args.scale, on_progress=progress)

    return run_reporting(job, args)
