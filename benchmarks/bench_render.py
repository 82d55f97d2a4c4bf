"""Benchmark ``dcseg.render`` backends against the reference (run by hand).

    python benchmarks/bench_render.py --out benchmarks/results/render.json

Each case (backend x scene x channels) runs in a fresh subprocess so that ``ru_maxrss`` is that
case's peak resident memory (torch allocations included). Reports the median wall time of
forward and forward+backward (float32; one untimed warm-up run loads the numba cache).
Subprocesses get ``OMP_WAIT_POLICY=PASSIVE`` unless set: torch's and numba's OpenMP pools
otherwise spin against each other (and against other load) on a 2-core machine.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import torch

from dcseg.gaussians import Gaussians
from dcseg.render import Camera, render
from dcseg.render import torch_renderer as tr
from dcseg.render.projection import ALPHA_MIN

SCENES = {"30k@160x120": (30_000, 160, 120), "100k@320x240": (100_000, 320, 240)}
MEMORY_SCENES = {"100k@640x480": (100_000, 640, 480)}
"""Run with the ``cpu`` backend and 32 channels only, to check peak memory at full size."""
CHANNELS = (3, 32)
BACKENDS = ("cpu", "reference")


def make_scene(n: int, width: int, height: int, seed: int = 0) -> tuple[Gaussians, Camera]:
    """N random Gaussians filling a camera frustum 1-6 m deep, sized like a fitted scene."""
    gen = torch.Generator().manual_seed(seed)
    focal = 0.9 * width
    z = 1.0 + 5.0 * torch.rand(n, generator=gen)
    u = (torch.rand(n, generator=gen) * 1.2 - 0.1) * width
    v = (torch.rand(n, generator=gen) * 1.2 - 0.1) * height
    means = torch.stack([(u - width / 2) * z / focal, (v - height / 2) * z / focal, z], dim=1)
    # world size so that the projected sigma is ~1-3 px on average at this density
    px = math.sqrt(width * height / n)
    scale = px * z / focal
    log_scales = torch.log(scale)[:, None] + 0.5 * torch.randn(n, 3, generator=gen)
    gaussians = Gaussians(
        means,
        torch.randn(n, 4, generator=gen),
        log_scales,
        torch.randn(n, generator=gen),
        torch.zeros(n, 1, 3),
    )
    k = torch.tensor([[focal, 0.0, width / 2 - 0.5], [0.0, focal, height / 2 - 0.5], [0, 0, 1]])
    return gaussians, Camera(torch.eye(4), k, width, height)


def run_case(backend: str, scene: str, channels: int, repeats: int) -> dict[str, Any]:
    """Time one case in this process; returns timings, contributors per pixel and peak RSS."""
    n, width, height = {**SCENES, **MEMORY_SCENES}[scene]
    gaussians, camera = make_scene(n, width, height)
    params = [gaussians.means, gaussians.quats, gaussians.log_scales, gaussians.opacity_logits]
    for p in params:
        p.requires_grad_(True)
    values = torch.rand(n, channels, generator=torch.Generator().manual_seed(1))
    values.requires_grad_(True)
    fwd, fwd_bwd, fwd_bwd_cpu = [], [], []
    warmup = int(backend != "reference")  # an untimed first run loads the numba cache
    for _ in range(repeats + warmup):
        start = time.perf_counter()
        with torch.no_grad():
            render(gaussians, values, camera, backend=backend)
        fwd.append(time.perf_counter() - start)
        start, start_cpu = time.perf_counter(), time.process_time()
        out = render(gaussians, values, camera, backend=backend)
        (out.values.sum() + out.depth.sum()).backward()  # type: ignore[no-untyped-call]
        fwd_bwd.append(time.perf_counter() - start)
        fwd_bwd_cpu.append(time.process_time() - start_cpu)
    return {
        "backend": backend,
        "scene": scene,
        "channels": channels,
        "repeats": repeats,
        "forward_s": statistics.median(fwd[warmup:]),
        "forward_backward_s": statistics.median(fwd_bwd[warmup:]),
        "forward_backward_cpu_s": statistics.median(fwd_bwd_cpu[warmup:]),
        "load_average_1min": os.getloadavg()[0],
        "mean_alpha": float(out.alpha.detach().mean()),
        "contributors_per_pixel": contributors(gaussians, camera) if backend == "cpu" else None,
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
    }


def contributors(gaussians: Gaussians, camera: Camera) -> float:
    """Mean number of Gaussians actually composited per pixel (alpha >= 1/255, before stop)."""
    from dcseg.render.projection import project

    with torch.no_grad():
        sp = project(gaussians, camera)
        counter = {"n": 0.0}

        def count(means2d, conics, opacities, values, pixels):  # same maths as `composite`
            d = means2d[None] - pixels[:, None]
            a, b, c = conics.unbind(-1)
            sigma = 0.5 * (a * d[..., 0] ** 2 + c * d[..., 1] ** 2) + b * d[..., 0] * d[..., 1]
            alpha = torch.clamp(opacities * torch.exp(-sigma), max=tr.ALPHA_MAX)
            alpha = torch.where(alpha >= ALPHA_MIN, alpha, torch.zeros_like(alpha))
            alive = torch.cumprod(1.0 - alpha, dim=1) > tr.T_MIN
            counter["n"] += float(((alpha > 0) & alive).sum())
            return torch.zeros(pixels.shape[0], values.shape[1])

        original = tr.composite
        tr.composite = count
        try:
            tr.rasterize_reference(sp, torch.ones(len(sp), 1), camera.width, camera.height)
        finally:
            tr.composite = original
    return counter["n"] / (camera.width * camera.height)


def _subprocess(backend: str, scene: str, channels: int, repeats: int) -> dict[str, Any]:
    cmd = [sys.executable, __file__, "--case", backend, scene, str(channels), str(repeats)]
    env = {**os.environ, "OMP_WAIT_POLICY": os.environ.get("OMP_WAIT_POLICY", "PASSIVE")}
    done = subprocess.run(cmd, check=True, capture_output=True, text=True, env=env)
    result: dict[str, Any] = json.loads(done.stdout.strip().splitlines()[-1])
    return result


def _table(rows: list[dict[str, Any]]) -> str:
    lines = [
        "| scene | C | backend | fwd ms | fwd+bwd ms | fwd+bwd CPU-time ms | speed-up fwd+bwd "
        "| peak RSS MB | contrib/px | load avg |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    ref = {(r["scene"], r["channels"]): r for r in rows if r["backend"] == "reference"}
    contrib = {r["scene"]: r["contributors_per_pixel"] for r in rows if r["backend"] == "cpu"}
    for r in rows:
        base = ref.get((r["scene"], r["channels"]))
        speed = f"{base['forward_backward_s'] / r['forward_backward_s']:.1f}x" if base else "-"
        lines.append(
            f"| {r['scene']} | {r['channels']} | {r['backend']} | {1e3 * r['forward_s']:.1f} | "
            f"{1e3 * r['forward_backward_s']:.1f} | {1e3 * r['forward_backward_cpu_s']:.1f} | "
            f"{speed} | {r['peak_rss_mb']:.0f} | {contrib.get(r['scene'], float('nan')):.1f} | "
            f"{r['load_average_1min']:.1f} |"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/render.json"))
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--reference-repeats", type=int, default=3)
    parser.add_argument("--reference-repeats-large", type=int, default=1)
    parser.add_argument("--case", nargs=4, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.case:
        backend, scene, channels, repeats = args.case
        print(json.dumps(run_case(backend, scene, int(channels), int(repeats))))
        return
    rows = []
    for scene in SCENES:
        for channels in CHANNELS:
            for backend in BACKENDS:
                reps = args.repeats
                if backend == "reference":
                    large = SCENES[scene][0] > 50_000
                    reps = args.reference_repeats_large if large else args.reference_repeats
                rows.append(_subprocess(backend, scene, channels, reps))
                print(json.dumps(rows[-1]), file=sys.stderr)
    for scene in MEMORY_SCENES:
        rows.append(_subprocess("cpu", scene, 32, args.repeats))
    meta = {
        "torch": torch.__version__,
        "threads": torch.get_num_threads(),
        "omp_wait_policy": os.environ.get("OMP_WAIT_POLICY", "PASSIVE"),
        "load_average_at_end": os.getloadavg(),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"meta": meta, "cases": rows}, indent=2) + "\n")
    print(_table(rows))


if __name__ == "__main__":
    main()
