"""Options and error reporting shared by the verbs that run the segmentation pipeline."""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Callable
from typing import Any

from dcseg.cli._options import budget_fields, build, capture_fields
from dcseg.config import DEFAULT_SCALE, JobConfig
from dcseg.progress import Progress

log = logging.getLogger("dcseg")

Job = Callable[[Progress], dict[str, Any]]


def add_pipeline_options(parser: argparse.ArgumentParser) -> None:
    """``--preset --matcher --scale --label-maps --seed --overwrite --quiet``."""
    group = parser.add_argument_group("method")
    group.add_argument("--preset", choices=("fast", "paper"), default="fast", help="(fast)")
    group.add_argument(
        "--matcher", choices=("assignment", "matching"), default="assignment", help="(assignment)"
    )
    group.add_argument(
        "--scale", type=float, default=DEFAULT_SCALE, help="clustering scale in [0, 1]"
    )
    group.add_argument(
        "--label-maps",
        choices=("gaussians", "clusters"),
        default="gaussians",
        help="labels/ rendered from the Gaussians' final classes, as in the labelled PLY "
        "(gaussians), or from the cluster maps through each cluster's class (clusters)",
    )
    group.add_argument("--seed", type=int, default=0, help="seed of every random choice")
    add_reconstruct_flags(group)
    add_device_option(group)
    add_output_options(parser)


def add_reconstruct_flags(parser: Any) -> None:
    """``--surface-priors`` (discs centred on the observed depth) and ``--refine-poses``."""
    parser.add_argument(
        "--surface-priors",
        action="store_true",
        help="reconstruct thin discs pulled onto the observed depth, rendering the depth of "
        "their planes (surfaces within mm on clean depth): "
        "dcseg.reconstruct.config.SURFACE_PRIORS",
    )
    parser.add_argument(
        "--refine-poses",
        action="store_true",
        help="fit a pose correction per frame with the Gaussians, for captures whose poses "
        "come from tracking (handheld sensors, phones); later stages use the refined poses: "
        "dcseg.reconstruct.config.REFINE_POSES",
    )


def reconstruct_fields(args: argparse.Namespace) -> dict[str, Any]:
    """The reconstruction overrides of ``--surface-priors`` and ``--refine-poses``."""
    from dcseg.reconstruct.config import REFINE_POSES, SURFACE_PRIORS

    fields: dict[str, Any] = {}
    if getattr(args, "surface_priors", False):
        fields.update(SURFACE_PRIORS)
    if getattr(args, "refine_poses", False):
        fields.update(REFINE_POSES)
    return fields


def add_device_option(parser: Any) -> None:
    """``--device auto|cpu|cuda|cuda:N``: where reconstruction and training compute."""
    parser.add_argument(
        "--device",
        default="auto",
        help="auto (CUDA when present), cpu, cuda or cuda:N (auto)",
    )


def add_output_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--overwrite", action="store_true", help="replace an existing OUT")
    parser.add_argument("--quiet", action="store_true", help="no progress bars")


def job_config(args: argparse.Namespace) -> JobConfig:
    """The configs of ``--preset --scale --matcher --label-maps --seed``, the capture and
    budget flags."""
    segment = {
        "scale": args.scale,
        "matcher": args.matcher,
        "seed": args.seed,
        "label_maps": args.label_maps,
    }
    options = {
        "capture": capture_fields(args),
        "segment": segment,
        "budget": budget_fields(args),
        "reconstruct": reconstruct_fields(args),
    }
    return build(args.preset, options)


def run_reporting(job: Job, args: argparse.Namespace) -> int:
    """Run a job with progress bars; turn input errors into a listed report and exit 1."""
    from dcseg.cli._progress import StageBars
    from dcseg.cli.run import summary_line
    from dcseg.errors import InputError

    if args.out.exists() and any(args.out.iterdir()) and not args.overwrite:
        sys.stderr.write(f"dcseg: {args.out} is not empty; pass --overwrite to replace it\n")
        return 2
    try:
        with StageBars(enabled=not args.quiet) as bars:
            record = job(bars)
    except InputError as error:
        sys.stderr.write(f"dcseg: {len(error.problems)} problem(s):\n")
        sys.stderr.writelines(f"  - {p}\n" for p in error.problems)
        return 1
    if record.get("size_rules"):  # absent from runs made before the size rules
        from dcseg.sizes import summary

        log.info("%s", summary(record["size_rules"]))
    log.info("%s: %s", args.out, summary_line(record))
    return 0
