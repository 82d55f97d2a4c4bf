"""Reconstruct a ``dcseg synth`` scene with the fast preset, with and without surface priors.

    python -m benchmarks.surface_priors SCENE --work W --out results/surface_priors.json \\
        --variant plain='{}' \\
        --variant discs='{"init_thickness": 0.1, "thickness_weight": 1, "centre_weight": 10}'

Each variant is a JSON object of reconstruction overrides (``options.reconstruct`` of a job);
per variant: train time, held-out PSNR and depth MAE, and the opaque Gaussians' distance to
the true surfaces (:func:`bench_surface.measure`). Use ``dcseg synth --depth-sigma 0`` for
the noise-free depth the surface targets are stated on.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

from benchmarks.bench_surface import measure
from dcseg.jobs import reconstruct_job
from dcseg.options import JobOptions, build_config


def run_variant(scene: Path, out: Path, overrides: dict[str, Any]) -> dict[str, Any]:
    config = build_config("fast", JobOptions.model_validate({"reconstruct": overrides}))
    start = time.perf_counter()
    report = reconstruct_job(scene, config, out, device="cpu")
    row: dict[str, Any] = measure(out, scene)
    row.update(
        overrides=overrides,
        wall_seconds=round(time.perf_counter() - start, 1),
        train_seconds=report["seconds"]["train"],
    )
    return row


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("scene", type=Path)
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--variant", action="append", default=[], help="NAME=JSON")
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    rows = []
    for item in args.variant or ["plain={}"]:
        name, _, text = item.partition("=")
        row = {"variant": name, **run_variant(args.scene, args.work / name, json.loads(text))}
        print(json.dumps(row), flush=True)
        rows.append(row)
    if args.out is not None:
        args.out.write_text(json.dumps({"rows": rows}, indent=2) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
