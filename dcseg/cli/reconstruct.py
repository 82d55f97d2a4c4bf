"""``dcseg reconstruct``: fit 3D Gaussians to a posed RGB-D capture; write PLY and a report."""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path
from typing import Any

from dcseg.cli._options import add_flags, add_groups, build, options_of
from dcseg.cli._pipeline import add_device_option, add_reconstruct_flags, reconstruct_fields
from dcseg.config import JobConfig

log = logging.getLogger(__name__)


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "reconstruct",
        help="fit 3D Gaussians to a posed RGB-D capture",
        description="Initialise Gaussians from depth, optimise them against the colour and depth "
        "of the training frames, evaluate held-out frames, and write OUT/scene.ply (3DGS layout) "
        "and OUT/reconstruction.json (metrics, timings, config).",
    )
    parser.add_argument("capture", type=Path, help="capture folder or archive")
    parser.add_argument("--out", type=Path, required=True, help="output folder")
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="write into a non-empty OUT (replaces scene.ply, reconstruction.json, poses.json)",
    )
    parser.add_argument("--preset", choices=["fast", "paper"], default="fast", help="parameters")
    add_groups(parser, "reconstruct")
    add_flags(parser, "segment", only=("seed",))
    add_reconstruct_flags(parser)
    add_device_option(parser)
    add_groups(parser, "capture", "budget")
    parser.set_defaults(run=run)


def _config(args: argparse.Namespace) -> JobConfig:
    """The job config of the flags, through the one config builder."""
    options = options_of(args, "capture", "budget", "segment")
    options["reconstruct"] = reconstruct_fields(args)
    return build(args.preset, options)


def run(args: argparse.Namespace) -> int:
    from dcseg.cli._progress import StageBars
    from dcseg.errors import InputError
    from dcseg.jobs import reconstruct_job
    from dcseg.sizes import summary as rules_summary

    config = _config(args)  # a bad option exits first, naming its flag
    if args.out.is_dir() and any(args.out.iterdir()) and not args.overwrite:
        sys.stderr.write(f"dcseg reconstruct: {args.out} is not empty; pass --overwrite\n")
        return 2
    try:
        with StageBars() as bars:
            report = reconstruct_job(args.capture, config, args.out, bars, device=args.device)
    except InputError as error:
        for problem in error.problems:
            sys.stderr.write(f"dcseg reconstruct: {problem}\n")
        return 1
    log.info("%s", rules_summary(report["size_rules"]))
    log.info(
        "wrote %s (%d Gaussians); held-out PSNR %s dB, depth MAE %s m (surface depth %s m)",
        args.out / "scene.ply",
        report["gaussians"],
        report["psnr"],
        report["depth_mae"],
        report["surface_depth_mae"],
    )
    return 0
