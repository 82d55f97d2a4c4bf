"""Sizes of every export format for finished runs (``dcseg export``), and what each took once.

Usage::

    python benchmarks/bench_export.py runs/demo/run /tmp/bench40/run \\
        --out benchmarks/results/export.json

For every run and format, :func:`dcseg.export.export_run` writes a whole-run export (every
object and the scene-wide files, default options) into ``--work/<run>/<format>``; each row has
the run's Gaussian, object and view counts, the scene file's size, the sum of the per-object
files, the largest object file, the total written, and the wall seconds of that one call
(a single run on a shared machine: indicative, not a speed claim). Then ``ply`` with
``--sh-degree 3`` (strict loaders) is measured the same way.
"""

from __future__ import annotations

import argparse
import json
import platform
import tempfile
import time
from pathlib import Path
from typing import Any

from dcseg.export import FORMATS, ExportOptions, export_run
from dcseg.export.labelled import load_labelled_run


def measure(run: Path, out: Path, fmt: str, options: ExportOptions) -> dict[str, Any]:
    start = time.perf_counter()
    files = export_run(run, out, fmt, options=options)
    seconds = time.perf_counter() - start
    sizes = {p.name: p.stat().st_size for p in files}
    objects = [v for k, v in sizes.items() if k.startswith("instance_")]
    scene = next((k for k in sizes if k.startswith("scene.") or k == "scene_mesh.ply"), None)
    return {
        "format": fmt,
        "sh_degree": options.sh_degree,
        "scene_file": scene,
        "scene_bytes": sizes.get(scene) if scene else None,
        "object_files": len(objects),
        "object_bytes_total": sum(objects),
        "object_bytes_max": max(objects, default=0),
        "total_bytes": sum(sizes.values()),
        "seconds": round(seconds, 2),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("runs", type=Path, nargs="+", help="finished run folders")
    parser.add_argument("--out", type=Path, help="JSON results file")
    parser.add_argument("--work", type=Path, help="where exports go (default: a temp folder)")
    args = parser.parse_args()
    work = args.work or Path(tempfile.mkdtemp(prefix="bench-export-"))
    rows = []
    for run in args.runs:
        labelled = load_labelled_run(run)
        info = {
            "run": str(run),
            "gaussians": len(labelled.splats),
            "run_sh_degree": labelled.splats.sh_degree,
            "objects": len(labelled.instances),
            "views": labelled.record.get("counts", {}).get("views"),
            "scene_labelled_bytes": (run / "scene_labelled.ply").stat().st_size,
        }
        cases = [(f, ExportOptions()) for f in FORMATS] + [("ply", ExportOptions(sh_degree=3))]
        for fmt, options in cases:
            out = work / run.name / f"{fmt}-sh{options.sh_degree}"
            row = {**info, **measure(run, out, fmt, options)}
            print(json.dumps(row))
            rows.append(row)
    if args.out:
        body = {"machine": platform.platform(), "rows": rows}
        args.out.write_text(json.dumps(body, indent=1) + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
