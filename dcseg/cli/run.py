"""``dcseg run``: reconstruct, train, cluster, classify and export a capture."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from dcseg.cli._pipeline import add_pipeline_options, job_config, run_reporting


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "run",
        help="segment a capture end to end",
        description="Reconstruct Gaussians (unless --scene is given), train affinity features, "
        "cluster, classify with the class-aware masks and write the segmented scene to OUT.",
    )
    parser.add_argument("capture", type=Path, help="capture folder or archive")
    parser.add_argument("--agnostic-masks", type=Path, required=True, help="class-agnostic masks")
    parser.add_argument(
        "--semantic-masks",
        type=Path,
        help="class-aware maps; without them and --vocabulary the run is class-agnostic "
        "(objects without classes, instance metrics only)",
    )
    parser.add_argument("--vocabulary", type=Path, help="class names of --semantic-masks")
    parser.add_argument("--gt", type=Path, help="ground-truth PLY: also write metrics.json")
    parser.add_argument("--scene", type=Path, help="use this 3DGS scene.ply, skip reconstruction")
    parser.add_argument("--out", type=Path, required=True, help="output folder")
    add_pipeline_options(parser)
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from dcseg.jobs import RunInputs, run_job

    config = job_config(args)
    inputs = RunInputs(
        capture=args.capture,
        agnostic_masks=args.agnostic_masks,
        semantic_masks=args.semantic_masks,
        vocabulary=args.vocabulary,
        ground_truth=args.gt,
        scene=args.scene,
    )
    return run_reporting(
        lambda progress: run_job(inputs, config, args.out, progress, device=args.device), args
    )


def summary_line(record: dict[str, Any]) -> str:
    """One line for the terminal: counts and, with ground truth, the mIoU table."""
    counts = record["counts"]
    clusters = f"{counts['clusters']} clusters, {counts['labelled_clusters']} labelled"
    objects = counts.get("instances")  # absent from runs made before the object level
    text = clusters if objects is None else f"{objects} objects ({clusters})"
    if record.get("metrics_summary"):
        text += " | " + json.dumps(record["metrics_summary"])
    return text
