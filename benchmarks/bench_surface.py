"""How far a run's Gaussians sit from the true surfaces of a synthetic scene.

    python benchmarks/bench_surface.py RUN SCENE [RUN SCENE ...] --out surface.json

``RUN`` is a finished run (its ``scene.ply``) or a reconstruction folder; ``SCENE`` the
``dcseg synth`` bundle it was made from (its ``gt/points.ply`` samples the true surfaces). Per
run: the opaque Gaussians' (opacity > 0.5) centre distance to the surface
(:func:`dcseg.evaluate.surface.geometry_report`: median, 90th percentile, mean, share within
1 cm), the coverage gap (the share of true-surface points with no opaque centre within 5 cm)
and, when the run's ``run.json`` or ``reconstruction.json`` has them, the held-out PSNR and
depth MAE.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from dcseg.evaluate.surface import geometry_report
from dcseg.io.ground_truth import read_ground_truth_points
from dcseg.io.ply import read_gaussians_ply


def measure(run: Path, scene: Path) -> dict[str, Any]:
    g = read_gaussians_ply(run / "scene.ply")
    surface = read_ground_truth_points(scene / "gt" / "points.ply")
    report = geometry_report(g.means.detach().numpy(), g.opacities().detach().numpy(), surface)
    row: dict[str, Any] = {"run": str(run), "gaussians": len(g), **report["centre_to_surface"]}
    row["coverage_gap"] = report["coverage"]["gap"]
    row["median_to_centre"] = report["coverage"]["median_to_centre"]
    record, alone = run / "run.json", run / "reconstruction.json"
    rec: dict[str, Any] = {}
    if record.is_file():
        rec = json.loads(record.read_text(encoding="utf-8")).get("reconstruction", {})
    elif alone.is_file():
        rec = json.loads(alone.read_text(encoding="utf-8"))
    row["psnr"], row["depth_mae"] = rec.get("psnr"), rec.get("depth_mae")
    row["surface_depth_mae"] = rec.get("surface_depth_mae")
    return row


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("pairs", nargs="+", type=Path, help="RUN SCENE [RUN SCENE ...]")
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    if len(args.pairs) % 2:
        parser.error("give RUN SCENE pairs")
    rows = [measure(r, s) for r, s in zip(args.pairs[::2], args.pairs[1::2], strict=True)]
    for row in rows:
        print(json.dumps(row))
    if args.out is not None:
        args.out.write_text(json.dumps({"rows": rows}, indent=2) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
