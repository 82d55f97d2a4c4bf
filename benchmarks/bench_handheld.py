"""Reconstruction quality under a handheld sensor's faults: noisy depth, pose error, motion blur.

    python -m benchmarks.bench_handheld --work W --seeds 0 1 --out results/handheld.json \\
        --variant sharp='{}' \\
        --variant handheld='{"depth_sigma": 0.00285, "pose_error_deg": 0.5,
                             "pose_error_m": 0.01, "motion_blur_px": 3}'

Each variant is a JSON object of :class:`dcseg.synth.SynthConfig` fields on top of ``--frames``,
``--size`` and the ``default`` noise level, plus optionally ``"reconstruct"`` (reconstruction
overrides, as a job's ``options.reconstruct``) and ``"scene"`` (the name of another variant
whose scenes to reuse: same synth fields, another reconstruction). Per variant and scene seed
the scene is generated, reconstructed with the fast preset (``dcseg.jobs.reconstruct_job``, what
``dcseg reconstruct`` runs) and scored: held-out PSNR against the capture's colour (blurred
when the variant blurs, as a real capture's held-out frames are) and against the sharp colour,
depth MAE against the capture's noisy depth (what a real capture can measure) and against the
true depth, and the opaque Gaussians' distance to the true surfaces. With pose refinement the
held-out views are scored at their aligned poses (the run's ``poses.json``).
Scenes and runs already in ``--work`` are reused.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from benchmarks.bench_surface import measure
from dcseg.io.ply import read_gaussians_ply
from dcseg.io.poses import POSES_FILE, read_poses
from dcseg.jobs import reconstruct_job
from dcseg.options import JobOptions, build_config
from dcseg.reconstruct.evaluate import evaluate
from dcseg.reconstruct.poses import pose_change
from dcseg.reconstruct.views import make_view
from dcseg.synth import SynthConfig, SynthScene, generate_scene, write_scene
from dcseg.synth.generate import true_poses as rendered_poses
from dcseg.types import Frame


def parse_size(text: str) -> tuple[int, int]:
    width, _, height = text.partition("x")
    return int(width), int(height)


def truth_frames(cfg: SynthConfig, names: list[str], poses: dict[str, Any] | None) -> list[Frame]:
    """The named frames with sharp colour and the true depth (the scene without blur), at
    ``poses`` when given (refined), else at the capture's."""
    sharp: SynthScene = generate_scene(replace(cfg, motion_blur_px=0.0))
    depth = dict(zip((f.name for f in sharp.capture.frames), sharp.gt_depth, strict=True))
    by_name = {f.name: f for f in sharp.capture.frames}
    frames = [replace(by_name[n], depth=depth[n]) for n in names]
    if poses is None:
        return frames
    return [replace(f, c2w=np.asarray(poses[f.name], dtype=np.float64)) for f in frames]


def true_poses(cfg: SynthConfig) -> dict[str, NDArray[np.float64]]:
    """The poses the scene's images were rendered from (before ``pose_error_*``)."""
    poses = rendered_poses(cfg)
    return {f"frame_{i:04d}": pose for i, pose in enumerate(poses)}


def rigid_fit(source: NDArray[np.float64], target: NDArray[np.float64]) -> NDArray[np.float64]:
    """``[4, 4]`` rigid transform taking the points ``source`` closest to ``target`` (Kabsch)."""
    mu_s, mu_t = source.mean(axis=0), target.mean(axis=0)
    u, _, vt = np.linalg.svd((source - mu_s).T @ (target - mu_t))
    d = np.sign(np.linalg.det(vt.T @ u.T))
    rot = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = rot, mu_t - rot @ mu_s
    return out


def pose_errors(truth: dict[str, NDArray[np.float64]], poses: dict[str, Any]) -> dict[str, float]:
    """Median rotation (degrees) and camera-centre (metres) error of ``poses`` against truth,
    as they are and after the one rigid transform that best aligns all camera centres (a
    reconstruction moved rigidly as a whole is as good as one that is not)."""
    names = sorted(poses)
    given = {n: np.asarray(poses[n], dtype=np.float64) for n in names}
    centres = np.stack([given[n][:3, 3] for n in names])
    fit = rigid_fit(centres, np.stack([truth[n][:3, 3] for n in names]))
    out: dict[str, float] = {}
    for key, moved in (("", given), ("aligned_", {n: fit @ given[n] for n in names})):
        degrees, metres = zip(*(pose_change(truth[n], moved[n]) for n in names), strict=True)
        out[key + "deg"] = round(statistics.median(degrees), 4)
        out[key + "m"] = round(statistics.median(metres), 5)
    return out


def refined_poses(run: Path) -> dict[str, Any] | None:
    """The run's refined poses (its ``poses.json``), None when it did not refine them (the
    file also holds the cameras of a registration or intrinsics correction alone)."""
    path = run / POSES_FILE
    report = json.loads((run / "reconstruction.json").read_text(encoding="utf-8"))
    refined = report.get("pose_refinement") is not None
    return dict(read_poses(path)) if refined and path.is_file() else None


def score_poses(scene: Path, run: Path, cfg: SynthConfig) -> dict[str, Any]:
    """Pose error of the capture's poses and, when refined, of the refined poses."""
    truth = true_poses(cfg)
    capture = json.loads((scene / "capture.json").read_text(encoding="utf-8"))
    given = {f["name"]: f["c2w"] for f in capture["frames"]}
    out = {"pose_error_given": pose_errors(truth, given)}
    refined = refined_poses(run)
    if refined is not None:
        out["pose_error_refined"] = pose_errors(truth, refined)
    return out


def score_against_truth(run: Path, cfg: SynthConfig, report: dict[str, Any]) -> dict[str, float]:
    """Held-out PSNR against sharp colour and depth MAE against true depth."""
    gaussians = read_gaussians_ply(run / "scene.ply")
    frames = truth_frames(cfg, report["test_frames"], refined_poses(run))
    views = [make_view(f, 1, "cpu") for f in frames]
    planar = bool(report["config"].get("planar_depth", False))
    metrics = evaluate(gaussians, views, None, planar=planar)
    return {
        "sharp_psnr": round(metrics.psnr, 3),
        "true_depth_mae": round(metrics.depth_mae, 5),
        "true_surface_depth_mae": round(metrics.surface_depth_mae, 5),
    }


def ensure_scene(scene: Path, cfg: SynthConfig) -> None:
    """Generate ``scene`` unless it exists; an existing one must have been made with ``cfg``."""
    if not (scene / "capture.json").is_file():
        write_scene(generate_scene(cfg), scene)
        return
    made = json.loads((scene / "scene.json").read_text(encoding="utf-8"))
    wanted = {
        "seed": cfg.seed,
        "noise": cfg.noise,
        "size": [cfg.width, cfg.height],
        "frames": cfg.frames,
        "pose_error": {"deg": cfg.pose_error_deg, "m": cfg.pose_error_m},
        "motion_blur_px": cfg.motion_blur_px,
        "motion_blur_share": cfg.motion_blur_share,
        "depth_sigma": cfg.level().depth_sigma,
        "error_model": cfg.segmenter(),
        "depth_shift_px": list(cfg.depth_shift_px),
    }
    found = {key: made.get(key) for key in wanted}
    found["depth_shift_px"] = made.get("depth_shift_px", [0, 0])  # before the shift
    found["motion_blur_share"] = made.get("motion_blur_share", 1.0)  # before the share
    if "error_model" not in made:  # scenes made before the generators: the level's masks
        found["error_model"] = "realistic" if made["noise"] == "realistic" else None
    found["depth_sigma"] = made["noise_level"]["depth_sigma"]
    if found != wanted:
        raise SystemExit(f"{scene} was made with {found}, this variant needs {wanted}")


def run_one(scene: Path, run: Path, cfg: SynthConfig, overrides: dict[str, Any]) -> dict[str, Any]:
    """Generate (or reuse) the scene, reconstruct (or reuse) it and score the result."""
    ensure_scene(scene, cfg)
    report_path = run / "reconstruction.json"
    if not report_path.is_file():
        job = JobOptions.model_validate({"reconstruct": overrides})
        config = build_config("fast", job)
        start = time.perf_counter()
        reconstruct_job(scene, config, run, device="cpu")
        print(f"reconstructed {scene} in {time.perf_counter() - start:.0f} s", flush=True)
    report = json.loads(report_path.read_text(encoding="utf-8"))
    row: dict[str, Any] = measure(run, scene)
    row.update(score_against_truth(run, cfg, report))
    row.update(score_poses(scene, run, cfg))
    row["train_seconds"] = report["seconds"]["train"]
    row["depth_noise_at_1m"] = report.get("depth_noise_at_1m")
    refinement = report.get("pose_refinement")
    if refinement is not None:
        row["pose_refinement"] = {k: v for k, v in refinement.items() if k != "poses"}
    row["reconstruct"] = overrides
    return row


def summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Mean and spread (min, max) of every metric over the seeds of a variant."""
    keys = ("psnr", "sharp_psnr", "depth_mae", "true_depth_mae", "median", "p90", "within_1cm")
    out: dict[str, Any] = {}
    for key in keys:
        values = [float(r[key]) for r in rows if r.get(key) is not None]
        if values:
            out[key] = {
                "mean": round(statistics.fmean(values), 4),
                "min": round(min(values), 4),
                "max": round(max(values), 4),
            }
    return out


def _tuples(overrides: dict[str, Any]) -> dict[str, Any]:
    """``overrides`` with JSON lists (``depth_shift_px``) as the tuples SynthConfig holds."""
    return {k: tuple(v) if isinstance(v, list) else v for k, v in overrides.items()}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--variant", action="append", default=[], help="NAME=JSON")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--size", type=parse_size, default=(320, 240))
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    results: dict[str, Any] = {"frames": args.frames, "size": list(args.size), "variants": {}}
    for item in args.variant or ["sharp={}"]:
        name, _, text = item.partition("=")
        overrides = json.loads(text)
        reconstruct = overrides.pop("reconstruct", {})
        scene_name = overrides.pop("scene", name)
        rows = []
        for seed in args.seeds:
            cfg = SynthConfig(seed=seed, frames=args.frames, width=args.size[0],
                              height=args.size[1], **_tuples(overrides))  # fmt: skip
            scene = args.work / scene_name / f"s{seed}" / "scene"
            run = args.work / name / f"s{seed}" / "run"
            row = {"variant": name, "seed": seed, **run_one(scene, run, cfg, reconstruct)}
            print(json.dumps(row), flush=True)
            rows.append(row)
        results["variants"][name] = {
            "synth": overrides,
            "reconstruct": reconstruct,
            "rows": rows,
            "summary": summary(rows),
        }
    if args.out is not None:
        args.out.write_text(json.dumps(results, indent=2) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
