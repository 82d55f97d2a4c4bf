"""Command-line options shared by every verb that reads a capture."""

from __future__ import annotations

import argparse
from typing import Any

from dcseg.config import CaptureOptions, JobConfig, PipelineConfig
from dcseg.errors import InputError
from dcseg.options import build_config, parse_options


def parse_size(text: str) -> tuple[int, int]:
    """Parse ``WxH`` (e.g. ``320x240``) into ``(width, height)``."""
    try:
        width, height = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"size must look like 320x240, got {text!r}") from None
    if width < 1 or height < 1:
        raise argparse.ArgumentTypeError(f"size must be positive, got {text!r}")
    return width, height


def parse_intrinsics(text: str) -> tuple[float, float, float, float]:
    """Parse ``fx,fy,cx,cy`` into four floats."""
    try:
        fx, fy, cx, cy = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"intrinsics must look like 600,600,599.5,339.5 (fx,fy,cx,cy), got {text!r}"
        ) from None
    return fx, fy, cx, cy


def add_capture_options(parser: argparse.ArgumentParser) -> None:
    """Add ``--stride --max-frames --size --depth-trunc --intrinsics --min-confidence`` to a
    verb's parser."""
    group = parser.add_argument_group("capture options")
    group.add_argument("--stride", type=int, default=1, help="keep every N-th frame")
    group.add_argument("--max-frames", type=int, help="keep at most N frames (after --stride)")
    group.add_argument("--size", type=parse_size, help="downscale frames to WxH")
    group.add_argument("--depth-trunc", type=float, help="ignore depth beyond this many metres")
    group.add_argument(
        "--intrinsics",
        type=parse_intrinsics,
        help="fx,fy,cx,cy at native resolution, for layouts without stored intrinsics",
    )
    group.add_argument(
        "--min-confidence",
        type=int,
        default=0,
        help="Record3D/Polycam: drop depth below this ARKit confidence level "
        "(0 low, 1 medium, 2 high; default 0 = keep all)",
    )


def parse_cap(text: str) -> int | str:
    """An integer (``640``) or a word (``native``, ``all``); the config builder checks which."""
    return int(text) if text.strip().lstrip("-").isdigit() else text.strip().lower()


def add_budget_options(parser: argparse.ArgumentParser) -> None:
    """Add ``--max-side N|native --keyframes N|all`` (the preset's frame budget otherwise)."""
    group = parser.add_argument_group("frame budget (default: the preset's)")
    group.add_argument(
        "--max-side",
        type=parse_cap,
        help="train at the capture's resolution divided by the smallest integer factor that "
        "brings its longer side to at most N pixels; native = full resolution "
        "(fast 640, paper 1600); outputs stay at the capture's resolution",
    )
    group.add_argument(
        "--keyframes",
        type=parse_cap,
        help="train on at most N keyframes chosen by camera motion, evenly spaced; "
        "all = every frame that moved (fast 200, paper 1000)",
    )


def budget_fields(args: argparse.Namespace) -> dict[str, Any]:
    """The ``budget`` job options of the flags added by :func:`add_budget_options` (given only)."""
    given = {"max_side": args.max_side, "max_frames": args.keyframes}
    return {key: value for key, value in given.items() if value is not None}


FLAGS = {
    "capture.stride": "--stride",
    "capture.max_frames": "--max-frames",
    "capture.size": "--size",
    "capture.depth_trunc": "--depth-trunc",
    "capture.intrinsics": "--intrinsics",
    "capture.min_confidence": "--min-confidence",
    "segment.scale": "--scale",
    "segment.matcher": "--matcher",
    "segment.label_maps": "--label-maps",
    "segment.seed": "--seed",
    "budget.max_side": "--max-side",
    "budget.max_frames": "--keyframes",
}
"""The flag of each job option the CLI sets (named in error messages)."""


def capture_fields(args: argparse.Namespace) -> dict[str, Any]:
    """The ``capture`` job options of the flags added by :func:`add_capture_options`."""
    return {
        "stride": args.stride,
        "max_frames": args.max_frames,
        "size": args.size,
        "depth_trunc": args.depth_trunc,
        "intrinsics": args.intrinsics,
        "min_confidence": args.min_confidence,
    }


def build(preset: str | PipelineConfig, options: dict[str, Any]) -> JobConfig:
    """The configs of ``options`` through the one builder the API and the worker use
    (:func:`dcseg.options.build_config`); exits naming the flag of a refused value."""
    try:
        return build_config(preset, parse_options(options))
    except InputError as error:
        lines = [f"{_flag(p.path)}: {p.reason}" for p in error.problems]
        raise SystemExit("dcseg: " + "; ".join(lines)) from None


def rebuild(stored: PipelineConfig, options: dict[str, Any]) -> JobConfig:
    """A stored run's config with ``options`` (e.g. ``{"segment": {"scale": 0.5}}``), through
    the same builder and with the same error report as :func:`build`."""
    return build(stored, options)


def _flag(path: str) -> str:
    field = path.removeprefix("options.")
    for name, flag in FLAGS.items():
        if field == name or field.startswith(name + "."):
            return f"{flag} ({path})"
    return path


def capture_options(args: argparse.Namespace) -> CaptureOptions:
    """:class:`CaptureOptions` from the flags added by :func:`add_capture_options`."""
    return build("fast", {"capture": capture_fields(args)}).capture
