"""Benchmark per-view exposure: synthetic scenes with auto exposure, exposure fitted or off.

Usage::

    python benchmarks/bench_exposure.py --seeds 0 3 --spread 0.2

For each seed, ``dcseg synth --exposure-spread SPREAD`` (40 views 320x240, default noise) is
reconstructed with the fast preset twice, ``--exposure auto`` (the default) and ``off``; each
entry of ``benchmarks/results/exposure.json`` holds the held-out PSNR raw and colour-compensated,
the depth MAE, the wall time, what the detection measured, and how far the fitted per-view
gains are from the true ones (log gain, both relative to the training views' geometric mean).
Spread 0 checks that a constant exposure is left alone.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.bench_reconstruct import dcseg, run_reconstruct

RESULTS = Path(__file__).resolve().parent / "results" / "exposure.json"


def true_log_gains(seed: int, spread: float, frames: int) -> dict[str, list[float]]:
    """Per frame name the log gains the synthetic camera applied."""
    from dcseg.synth.generate import SynthConfig, exposure_gains

    gains = exposure_gains(SynthConfig(seed=seed, frames=frames, exposure_spread=spread))
    return {f"frame_{i:04d}": np.log(g).tolist() for i, g in enumerate(gains)}


def gain_error(report: dict[str, Any], truth: dict[str, list[float]]) -> float | None:
    """Median absolute difference of fitted and true log gains over the training views, both
    relative to their mean (the scene's reference exposure is free)."""
    fitted = (report.get("sensor") or {}).get("exposure", {}).get("fitted")
    if not fitted:
        return None
    names = list(fitted["views"])
    got = np.log([fitted["views"][n]["gain"] for n in names])
    want = np.array([truth[n] for n in names])
    diff = (got - got.mean(axis=0)) - (want - want.mean(axis=0))
    return float(np.median(np.abs(diff)))


def entry(report: dict[str, Any], truth: dict[str, list[float]], label: str) -> dict[str, Any]:
    exposure = dict((report.get("sensor") or {}).get("exposure", {}))
    fitted = exposure.get("fitted")
    if fitted:
        exposure["fitted"] = {k: v for k, v in fitted.items() if k != "views"}
    return {
        "exposure": label,
        "psnr": report["psnr"],
        "psnr_colour_compensated": report.get("psnr_colour_compensated"),
        "psnr_neighbour_exposure": report.get("psnr_neighbour_exposure"),
        "depth_mae": report["depth_mae"],
        "wall_seconds": report["wall_seconds"],
        "cpu_seconds": report["cpu_seconds"],
        "seconds": report["seconds"],
        "gaussians": report["gaussians"],
        "detected": exposure,
        "log_gain_error": gain_error(report, truth),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    parser.add_argument("--spread", type=float, default=0.2)
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--modes", nargs="+", default=["auto", "off"])
    parser.add_argument("--results", type=Path, default=RESULTS)
    args = parser.parse_args()
    results: dict[str, Any] = {}
    if args.results.exists():
        results = json.loads(args.results.read_text())
    for seed in args.seeds:
        truth = true_log_gains(seed, args.spread, args.frames)
        with tempfile.TemporaryDirectory(prefix="dcseg-exposure-") as tmp:
            capture = Path(tmp) / "synth"
            size = ["--frames", str(args.frames), "--size", "320x240", "--seed", str(seed)]
            dcseg("synth", str(capture), *size, "--exposure-spread", str(args.spread))
            for mode in args.modes:
                out = Path(tmp) / f"out_{mode}"
                extra = ["--preset", "fast", "--exposure", mode]
                report = run_reconstruct(capture, out, extra)
                key = f"synth_seed{seed}_spread{args.spread:g}_{mode}"
                results[key] = {"seed": seed, "spread": args.spread, **entry(report, truth, mode)}
                results[key]["command"] = " ".join(sys.argv)
                args.results.parent.mkdir(parents=True, exist_ok=True)
                args.results.write_text(json.dumps(results, indent=2) + "\n")
                shown = ("psnr", "psnr_colour_compensated", "psnr_neighbour_exposure", "depth_mae")
                print(key, {k: results[key][k] for k in shown}, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
