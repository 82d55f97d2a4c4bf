"""``dcseg reclassify``: label a finished run's instances with other class masks."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from dcseg.cli._pipeline import add_output_options, run_reporting
from dcseg.progress import Progress


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "reclassify",
        help="re-classify a run with another segmenter's masks (no retraining)",
        description="Assign classes to the instances of RUN from new class-aware masks and "
        "vocabulary, and write a complete new output to OUT; nothing is trained again.",
    )
    parser.add_argument("run_dir", type=Path, metavar="RUN", help="a finished run folder")
    parser.add_argument("--semantic-masks", type=Path, required=True, help="class-aware maps")
    parser.add_argument("--vocabulary", type=Path, required=True, help="class names")
    parser.add_argument("--out", type=Path, required=True, help="output folder")
    add_output_options(parser)
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from dcseg.jobs import RunInputs, resegment_job

    inputs = RunInputs(
        capture=args.run_dir, semantic_masks=args.semantic_masks, vocabulary=args.vocabulary
    )

    def job(progress: Progress) -> dict[str, Any]:
        return resegment_job(args.run_dir, args.out, inputs, on_progress=progress)

    return run_reporting(job, args)
