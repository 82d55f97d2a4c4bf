"""``dcseg synth``: generate a synthetic indoor scene with simulated masks and ground truth."""

from __future__ import annotations

import argparse
import logging
import shutil
import sys
from pathlib import Path
from typing import Any

from dcseg.cli._options import parse_size

logger = logging.getLogger(__name__)

NOISE_CHOICES = ("clean", "default", "heavy", "realistic")
ERROR_MODEL_CHOICES = ("realistic", "detector", "lowres")
"""The names of :data:`dcseg.synth.errors.ERROR_MODELS` (kept here: `--help` imports no numpy)."""


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "synth",
        help="generate a synthetic scene with ground truth",
        description="Render a seeded synthetic room with pybullet into OUT: a dcseg capture, "
        "simulated class-agnostic and class-aware 2D masks, a vocabulary, ground-truth points "
        "and per-frame ground-truth maps, and scene.json. Needs pip install 'dcseg[synth]'.",
    )
    parser.add_argument("out", type=Path, help="output folder (created if missing)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    parser.add_argument("--frames", type=int, default=40, help="number of views (default 40)")
    parser.add_argument(
        "--size", type=parse_size, default=(320, 240), help="image size WxH (default 320x240)"
    )
    parser.add_argument(
        "--noise",
        choices=NOISE_CHOICES,
        default="default",
        help="mask/depth noise level; realistic = consistent segmenter failures (look-alike "
        "classes, missed rare objects, coarse maps, merged and missing masks) and a larger "
        "vocabulary",
    )
    parser.add_argument(
        "--error-model",
        choices=ERROR_MODEL_CHOICES,
        default="",
        metavar="NAME",
        help="make the masks with this segmenter-error generator instead of the noise level's "
        "(which then sets the depth noise only): realistic (look-alike classes in most views, "
        "coarse maps, merged and missing SAM masks), detector (detector boxes prompting SAM: "
        "size/appearance confusions, fat masks bleeding into neighbours, missed small objects, "
        "scores), lowres (1/8-resolution semantic segmenter with a confusion matrix in every "
        "view; SAM merging same-depth neighbours, leaving objects uncovered)",
    )
    parser.add_argument(
        "--depth-sigma",
        type=float,
        default=None,
        help="depth noise at 1 m in metres, growing with z squared (default: the noise level's)",
    )
    parser.add_argument(
        "--disparity-step",
        type=float,
        default=0.0,
        help="quantise the depth in disparity as Kinect v1 does: inverse depth in steps of this "
        "many 1/m (0.0029: 2.9 mm depth steps at 1 m, 18 mm at 2.5 m; default 0 = not)",
    )
    parser.add_argument(
        "--pose-error-deg",
        type=float,
        default=0.0,
        help="rotation error of the written poses, degrees (standard deviation; default 0)",
    )
    parser.add_argument(
        "--pose-error-m",
        type=float,
        default=0.0,
        help="translation error of the written poses per axis, metres (std; default 0)",
    )
    parser.add_argument(
        "--motion-blur",
        type=float,
        default=0.0,
        metavar="PX",
        help="blur colour by camera motion during the exposure, median length in pixels "
        "(0-50; default 0 = sharp)",
    )
    parser.add_argument(
        "--exposure-spread",
        type=float,
        default=0.0,
        metavar="SD",
        help="auto exposure and white balance: per-frame colour gains drifting smoothly along "
        "the trajectory, log gain with this standard deviation (0-1; default 0 = constant)",
    )
    parser.add_argument(
        "--depth-shift",
        type=_shift,
        default=(0, 0),
        metavar="DX,DY",
        help="colour/depth misregistration: move every depth map DX pixels right and DY "
        "down against the colour (each within +-16; default 0,0 = registered)",
    )
    parser.add_argument(
        "--motion-blur-share",
        type=float,
        default=1.0,
        metavar="SHARE",
        help="share of the views --motion-blur blurs, drawn at random (0-1; default 1 = all)",
    )
    parser.add_argument(
        "--supersample",
        type=int,
        default=2,
        help="render colour at this factor and area-average it (anti-aliasing; 1 = off; default 2)",
    )
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="replace OUT if it holds an earlier synth output",
    )
    parser.set_defaults(run=run)


def _shift(text: str) -> tuple[int, int]:
    """``"DX,DY"`` as two integers (argparse type of ``--depth-shift``)."""
    parts = text.split(",")
    try:
        dx, dy = (int(p) for p in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected DX,DY (two integers), got {text!r}") from None
    return dx, dy


def prepare_output(out: Path, overwrite: bool) -> str | None:
    """Make sure no stale files survive in ``out``; return why not, or None when ready."""
    if not out.exists() or not any(out.iterdir()):
        return None
    if not overwrite:
        return f"{out} is not empty; pass --overwrite to replace an earlier synth output"
    if not (out / "scene.json").is_file():
        return f"refusing to overwrite {out}: it is not a synth output (no scene.json)"
    shutil.rmtree(out)
    return None


def run(args: argparse.Namespace) -> int:
    from dcseg.errors import InputError
    from dcseg.synth import SynthConfig, generate_scene, write_scene

    try:
        cfg = SynthConfig(
            args.seed,
            args.frames,
            args.size[0],
            args.size[1],
            args.noise,
            args.supersample,
            depth_sigma=args.depth_sigma,
            disparity_step=args.disparity_step,
            pose_error_deg=args.pose_error_deg,
            pose_error_m=args.pose_error_m,
            motion_blur_px=args.motion_blur,
            motion_blur_share=args.motion_blur_share,
            error_model=args.error_model,
            exposure_spread=args.exposure_spread,
            depth_shift_px=args.depth_shift,
        )
    except ValueError as exc:
        sys.stderr.write(f"dcseg synth: {exc}\n")
        return 2
    problem = prepare_output(args.out, args.overwrite)
    if problem:
        sys.stderr.write(f"dcseg synth: {problem}\n")
        return 2
    try:
        scene = generate_scene(cfg)
    except InputError as exc:
        sys.stderr.write(f"dcseg synth: {exc}\n")
        return 1
    path = write_scene(scene, args.out)
    logger.info("scene written: %s", path)
    return 0
