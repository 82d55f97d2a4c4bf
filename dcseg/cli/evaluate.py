"""``dcseg evaluate``: score a finished run against ground-truth points."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "evaluate",
        help="score a run against a ground-truth PLY",
        description="Evaluate RUN against GT (x y z label): mIoU/mAcc for the paper's "
        "projection protocol, nearest-Gaussian transfer and the naive 2D-fusion baseline; "
        "writes RUN/metrics.json and prints the summary.",
    )
    parser.add_argument("run_dir", type=Path, metavar="RUN", help="a finished run folder")
    parser.add_argument("--gt", type=Path, required=True, help="ground-truth PLY")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from dcseg.errors import InputError
    from dcseg.jobs import evaluate_job

    try:
        metrics = evaluate_job(args.run_dir, args.gt)
    except InputError as error:
        sys.stderr.write(f"dcseg: {len(error.problems)} problem(s):\n")
        sys.stderr.writelines(f"  - {p}\n" for p in error.problems)
        return 1
    sys.stdout.write(json.dumps(metrics["summary"], indent=1) + "\n")
    return 0
