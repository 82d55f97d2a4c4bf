"""An RGB-only COLMAP capture against the same scene with depth: reconstruction and segmentation.

    python -m benchmarks.bench_rgbonly --work W --seeds 0 1 --frames 24 --size 160x120 \\
        --points 5000 --out benchmarks/results/rgbonly.json

Per scene seed: ``dcseg synth`` writes the scene (default noise level); the same frames are
written as an RGB-only COLMAP model (``images/`` + binary ``sparse/0``, no depth) with their
true poses and ``--points`` sparse points sampled from the observed surfaces with 1 % depth
noise (:func:`dcseg.io.captures.colmap_write.sample_sparse_points`, what structure from motion
would give). Both captures then go through ``dcseg run`` (fast preset, the scene's masks and
ground truth): held-out PSNR, Gaussians, wall time, segmentation mIoU (projection, nearest,
naive fusion) and instance F1 come from ``run.json``. Scenes and runs already in ``--work``
are reused.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from dcseg.io.captures import read_capture
from dcseg.io.captures.colmap_write import sample_sparse_points, write_colmap_rgb_only

NOISE = 0.01
"""Sparse points' depth error relative to depth."""


def synth(work: Path, seed: int, frames: int, size: str) -> Path:
    scene = work / f"scene_{seed}"
    if not (scene / "scene.json").is_file():
        args = ["synth", str(scene), "--seed", str(seed), "--frames", str(frames)]
        subprocess.run([sys.executable, "-m", "dcseg", *args, "--size", size], check=True)
    return scene


def as_colmap(scene: Path, points: int, seed: int) -> Path:
    out = scene.parent / f"{scene.name}_colmap"
    if not (out / "sparse" / "0" / "points3D.bin").is_file():
        capture = read_capture(scene)
        write_colmap_rgb_only(capture, sample_sparse_points(capture, points, NOISE, seed), out)
    return out


def run(scene: Path, capture: Path, out: Path) -> dict[str, Any]:
    """``dcseg run`` of ``capture`` with ``scene``'s masks and ground truth; its record."""
    if not (out / "run.json").is_file():
        start = time.perf_counter()
        args = [capture, "--out", out, "--agnostic-masks", scene / "masks" / "agnostic"]
        args += ["--semantic-masks", scene / "masks" / "semantic", "--quiet", "--overwrite"]
        args += ["--vocabulary", scene / "vocabulary.txt", "--gt", scene / "gt" / "points.ply"]
        subprocess.run([sys.executable, "-m", "dcseg", "run", *map(str, args)], check=True)
        (out / "wall_seconds.txt").write_text(f"{time.perf_counter() - start:.1f}\n")
    record = json.loads((out / "run.json").read_text())
    rec = record["reconstruction"]
    summary = record["metrics_summary"]
    return {
        "psnr": rec["psnr"],
        "depth_mae": rec["depth_mae"],
        "gaussians": rec["gaussians"],
        "initial_gaussians": rec["initial_gaussians"],
        "reconstruct_train_s": rec["seconds"]["train"],
        "run_wall_s": float((out / "wall_seconds.txt").read_text()),
        "geometry_median_mm": rec["geometry"]["centre_to_surface"]["median"] * 1000,
        "miou": {k: summary[k]["miou"] for k in ("dcseg_projection", "dcseg_nearest")},
        "naive_fusion_miou": summary["naive_fusion"]["miou"],
        "instance_f1": summary["instances"]["f1"],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    parser.add_argument("--frames", type=int, default=24)
    parser.add_argument("--size", default="160x120")
    parser.add_argument("--points", type=int, default=5000)
    parser.add_argument("--out", type=Path, required=True)
    a = parser.parse_args()
    rows = []
    for seed in a.seeds:
        scene = synth(a.work, seed, a.frames, a.size)
        colmap = as_colmap(scene, a.points, seed)
        for name, capture in (("depth", scene), ("rgb_only", colmap)):
            row = {"seed": seed, "capture": name, **run(scene, capture, a.work / f"{name}_{seed}")}
            print(json.dumps(row), flush=True)  # noqa: T201 - a benchmark's progress
            rows.append(row)
    setup = {"frames": a.frames, "size": a.size, "points": a.points, "point_noise": NOISE}
    a.out.write_text(json.dumps({"setup": setup, "runs": rows}, indent=1) + "\n")


if __name__ == "__main__":
    main()
