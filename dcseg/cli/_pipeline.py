"""Options and error reporting shared by the verbs that run the segmentation pipeline."""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Callable
from typing import Any

from dcseg.cli._options import add_groups, build, given, options_of
from dcseg.config import JobConfig
from dcseg.progress import Progress

log = logging.getLogger("dcseg")

Job = Callable[[Progress], dict[str, Any]]


def add_pipeline_options(parser: argparse.ArgumentParser) -> None:
    """``--preset``, the capture, budget and segment flags (:mod:`dcseg.cli._options`),
    ``--surface-priors --refine-poses --device --overwrite --quiet``."""
    parser.add_argument("--preset", choices=("fast", "paper"), default="fast", help="(fast)")
    add_groups(parser, "segment", "capture", "budget", "affinity")
    group = parser.add_argument_group("reconstruction")
    add_reconstruct_flags(group)
    add_device_option(group)
    add_output_options(parser)


def add_reconstruct_flags(parser: Any) -> None:
    """``--surface-priors`` (tight surfaces) and ``--refine-poses``."""
    parser.add_argument(
        "--surface-priors",
        action="store_true",
        help="tight surfaces: pull the discs onto the observed depth from the first step and "
        "render the depth of their planes (within mm on clean depth instead of ~1 cm, for "
        "some segmentation quality): dcseg.reconstruct.config.SURFACE_PRIORS",
    )
    parser.add_argument(
        "--refine-poses",
        action="store_true",
        help="always fit a pose correction per frame with the Gaussians (the same as "
        "--pose-refinement on; the default auto does when the depth shows misaligned poses); "
        "later stages use the refined poses: dcseg.reconstruct.config.REFINE_POSES",
    )


def reconstruct_fields(args: argparse.Namespace) -> dict[str, Any]:
    """The reconstruction overrides of ``--surface-priors``, ``--refine-poses`` and the
    reconstruction flags a verb has (``dcseg reconstruct --iterations``, ...)."""
    from dcseg.reconstruct.config import REFINE_POSES, SURFACE_PRIORS

    fields: dict[str, Any] = {}
    if getattr(args, "surface_priors", False):
        fields.update(SURFACE_PRIORS)
    if getattr(args, "refine_poses", False):
        fields.update(REFINE_POSES)
    return {**fields, **given(args, "reconstruct")}  # single flags win over the bundles


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
    """The config of ``--preset`` and every option flag given, through the one builder."""
    options = options_of(args, "segment", "capture", "budget", "affinity")
    options["reconstruct"] = reconstruct_fields(args)
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
