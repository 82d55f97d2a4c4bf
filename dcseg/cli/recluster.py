"""``dcseg recluster``: cluster a finished run at another scale, without retraining."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from dcseg.cli._pipeline import add_output_options, run_reporting
from dcseg.progress import Progress


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
    from dcseg.cli._options import rebuild
    from dcseg.jobs import resegment_job, stored_config

    def job(progress: Progress) -> dict[str, Any]:
        config = rebuild(stored_config(args.run_dir), {"segment": {"scale": args.scale}})
        return resegment_job(args.run_dir, args.out, config=config, on_progress=progress)

    return run_reporting(job, args)
