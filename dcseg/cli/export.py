"""``dcseg export``: a finished run's objects as Gaussian files (PLY, SPZ, .splat) or meshes."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any


def register(subparsers: Any) -> None:
    from dcseg.export import FORMATS

    parser = subparsers.add_parser(
        "export",
        help="export a run's objects as PLY, SPZ, .splat, GLB (splats or meshes), OBJ or USDZ",
        description="Write RUN's objects into OUT: one file per object (and scene-wide files "
        "when no --instance is given), instances.<format>.json with each object's record and "
        "file, and frame.json (world axes, up axis, the turn to glTF's Y-up). Meshes (glb-mesh, "
        "obj, usdz) are fused from the depth the run keeps in state/, or from --capture.",
    )
    parser.add_argument("run_dir", type=Path, metavar="RUN", help="a finished run folder")
    parser.add_argument("--format", required=True, choices=FORMATS, dest="fmt")
    parser.add_argument("--out", type=Path, required=True, help="output folder")
    parser.add_argument(
        "--instance",
        type=int,
        action="append",
        dest="instances",
        metavar="K",
        help="export object K only (repeatable; default: every object and the whole scene)",
    )
    parser.add_argument(
        "--color",
        choices=("instance", "class"),
        help="paint Gaussians / vertices in their object's or class's palette colour",
    )
    parser.add_argument(
        "--sh-degree",
        type=int,
        choices=range(4),
        metavar="D",
        help="pad (or cut) SH to degree D (default: 3 for ply, the INRIA layout; else the run's)",
    )
    parser.add_argument("--capture", type=Path, help="capture to mesh when RUN holds no depth")
    parser.add_argument("--voxel-size", type=float, help="TSDF voxel in metres (default: auto)")
    parser.add_argument(
        "--max-faces", type=int, default=20_000, help="triangles per object mesh (20000)"
    )
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from dcseg.errors import InputError
    from dcseg.export import ExportOptions, export_run

    try:
        options = ExportOptions(
            colour=args.color,
            sh_degree=args.sh_degree,
            capture=args.capture,
            voxel_size=args.voxel_size,
            max_faces=args.max_faces,
        )
        files = export_run(
            args.run_dir, args.out, args.fmt, instances=args.instances, options=options
        )
    except InputError as error:
        sys.stderr.write(f"dcseg export: {len(error.problems)} problem(s):\n")
        sys.stderr.writelines(f"  - {p}\n" for p in error.problems)
        return 1
    sys.stdout.writelines(f"{path}\n" for path in files)
    return 0
