"""``dcseg reconstruct``: fit 3D Gaussians to a posed RGB-D capture; write PLY and a report."""

from __future__ import annotations

import argparse
import json
import logging
import math
import platform
import resource
import sys
import time
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

from dcseg import __version__
from dcseg.cli._options import add_capture_options, build, capture_fields
from dcseg.cli._pipeline import add_device_option

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
    parser.add_argument("--preset", choices=["fast", "paper"], default="fast", help="parameters")
    parser.add_argument("--iterations", type=int, help="optimisation steps (overrides preset)")
    parser.add_argument("--holdout", type=int, help="hold out every N-th frame (0 = none)")
    parser.add_argument("--seed", type=int, help="random seed (default 0)")
    parser.add_argument("--sh-degree", type=int, choices=[0, 1, 2, 3], help="SH colour degree")
    parser.add_argument("--train-downscale", type=int, help="train at 1/N resolution")
    parser.add_argument(
        "--full-res-from", type=int, help="train at full resolution from this step on"
    )
    parser.add_argument("--backend", help="renderer backend (default: the renderer's choice)")
    add_device_option(parser)
    add_capture_options(parser)
    parser.set_defaults(run=run)


def _config(args: argparse.Namespace) -> tuple[Any, Any]:
    """``(ReconstructConfig, CaptureOptions)`` through the one config builder."""
    overrides = {
        "iterations": args.iterations,
        "holdout": args.holdout,
        "sh_degree": args.sh_degree,
        "train_downscale": args.train_downscale,
        "full_res_from": args.full_res_from,
        "backend": args.backend,
    }
    chosen = {key: value for key, value in overrides.items() if value is not None}
    options = {"reconstruct": chosen, "capture": capture_fields(args)}
    if args.seed is not None:
        options["segment"] = {"seed": args.seed}
    cfg, capture = build(args.preset, options)
    return cfg.reconstruct, capture


def _progress_bar(total: int) -> tuple[Any, Any]:
    from tqdm import tqdm

    bar = tqdm(total=total, desc="reconstruct", unit="it", file=sys.stderr, dynamic_ncols=True)

    def on_progress(iteration: int, total: int, loss: float) -> None:
        bar.update(iteration - bar.n)
        if iteration % 25 == 0 or iteration == total:
            bar.set_postfix(loss=f"{loss:.4f}")

    return bar, on_progress


def _finite(value: float) -> float | None:
    return value if math.isfinite(value) else None


def _versions() -> dict[str, str]:
    import numpy
    import torch

    return {
        "dcseg": __version__,
        "python": platform.python_version(),
        "torch": torch.__version__,
        "numpy": numpy.__version__,
    }


def _report(result: Any, cfg: Any, seconds: dict[str, float], backend: str) -> dict[str, Any]:
    metrics = result.metrics
    return {
        "psnr": _finite(metrics.psnr),
        "depth_mae": _finite(metrics.depth_mae),
        "views": [
            {
                "name": v.name,
                "psnr": _finite(v.psnr),
                "depth_mae": _finite(v.depth_mae),
                "depth_pixels": v.depth_pixels,
            }
            for v in metrics.views
        ],
        "gaussians": len(result.gaussians),
        "initial_gaussians": result.initial_count,
        "extent": result.extent,
        "train_frames": list(result.train_frames),
        "test_frames": list(result.test_frames),
        "final_loss": result.losses[-1] if result.losses else None,
        "seconds": {key: round(value, 3) for key, value in seconds.items()},
        "backend": backend,
        "peak_memory_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
        "seed": cfg.seed,
        "config": asdict(cfg),
        "versions": _versions(),
    }


def run(args: argparse.Namespace) -> int:
    from dcseg.devices import resolve_device
    from dcseg.errors import InputError
    from dcseg.io.captures import read_capture
    from dcseg.io.ply import write_gaussians_ply
    from dcseg.reconstruct import fit_gaussians
    from dcseg.render import select_backend

    cfg, options = _config(args)
    try:
        device = resolve_device(args.device)
        backend = select_backend(device, cfg.backend)
    except ValueError as error:
        sys.stderr.write(f"dcseg reconstruct: {error}\n")
        return 2
    seconds: dict[str, float] = {}
    start = time.perf_counter()
    try:
        capture = read_capture(args.capture, options)
    except InputError as error:
        for problem in error.problems:
            sys.stderr.write(f"dcseg reconstruct: {problem}\n")
        return 1
    seconds["read"] = time.perf_counter() - start
    log.info("read %d frames from %s", len(capture), args.capture)

    bar, on_progress = _progress_bar(cfg.iterations)
    with bar:
        result = fit_gaussians(
            capture, replace(cfg, backend=backend), device=device, on_progress=on_progress
        )
    seconds.update(result.seconds)

    start = time.perf_counter()
    args.out.mkdir(parents=True, exist_ok=True)
    write_gaussians_ply(args.out / "scene.ply", result.gaussians)
    seconds["write"] = time.perf_counter() - start
    report = _report(result, cfg, seconds, backend)
    (args.out / "reconstruction.json").write_text(json.dumps(report, indent=2) + "\n")
    log.info(
        "wrote %s (%d Gaussians); held-out PSNR %s dB, depth MAE %s m",
        args.out / "scene.ply",
        len(result.gaussians),
        report["psnr"],
        report["depth_mae"],
    )
    return 0
