"""What the reconstruction's sensor checks measure, without reconstructing: pose misalignment
(:mod:`dcseg.reconstruct.pose_check`), colour/depth misregistration
(:mod:`dcseg.reconstruct.registration`) and wrong intrinsics
(:mod:`dcseg.reconstruct.calibration`, on the registered frames) on synthetic scenes with and
without the effect, and on real captures.

    python -m benchmarks.bench_detect --seeds 0 1 2 3 --out benchmarks/results/detect.json \\
        --variant exact='{}' --variant pose_0.1='{"pose_error_deg": 0.1, "pose_error_m": 0.002}' \\
        --variant pose_0.5='{"pose_error_deg": 0.5, "pose_error_m": 0.01}' \\
        --variant shift_3_0='{"depth_shift_px": [3, 0]}' \\
        --capture /work/shared/data/replica_room0_small=600,600,599.5,339.5

Each variant is a JSON object of :class:`dcseg.synth.SynthConfig` fields on top of
``--frames`` and ``--size`` (plus ``given_focal_scale`` / ``given_principal_shift``: the
intrinsics handed over are that wrong); each capture is ``PATH=fx,fy,cx,cy``. Per scene the training
frames (every 8th held out, as ``reconstruct`` does) are measured: the depth agreement ratio
and whether ``auto`` would refine the poses, the estimated shift, its gain and whether
``auto`` would apply it, and the seconds each check took.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any

from dcseg.reconstruct import calibration, pose_check, registration
from dcseg.reconstruct.sensor import sensor_report
from dcseg.reconstruct.views import split_frames
from dcseg.types import Frame


def measure(frames: tuple[Frame, ...]) -> dict[str, Any]:
    """Both checks on the training frames of ``frames``."""
    train, _ = split_frames(frames, 8)
    start = time.perf_counter()
    poses = sensor_report(train, drop_flying=True)["poses"]
    middle = time.perf_counter()
    shift = registration.estimate(train)
    end = time.perf_counter()
    applied = registration.decide("auto", (0, 0), shift)
    intrinsics = calibration.estimate(registration.registered(train, applied))
    fix = calibration.decide("auto", intrinsics)
    done = time.perf_counter()
    return {
        "pose_ratio": None if poses is None else round(poses["ratio"], 4),
        "tilt_deg": None if poses is None else round(poses["tilt_deg"], 4),
        "depth_disagreement_mm": None if poses is None else poses["depth_disagreement"] * 1000,
        "expected_from_noise_mm": None if poses is None else poses["expected_from_noise"] * 1000,
        "refine": pose_check.decide("auto", poses),
        "shift": shift,
        "applied": applied.record(),
        "intrinsics": intrinsics,
        "intrinsics_applied": None if fix is None else asdict(fix.apply(train[0].intrinsics)),
        "seconds": {
            "sensor": round(middle - start, 3),
            "registration": round(end - middle, 3),
            "intrinsics": round(done - end, 3),
        },
    }


def synthetic(args: argparse.Namespace) -> dict[str, Any]:
    from dcseg.synth import SynthConfig, generate_scene

    out: dict[str, Any] = {}
    for item in args.variant:
        name, _, text = item.partition("=")
        given: dict[str, Any] = json.loads(text)
        fields: dict[str, Any] = {
            k: tuple(v) if isinstance(v, list) else v for k, v in given.items()
        }
        scale = float(fields.pop("given_focal_scale", 1.0))
        shift = fields.pop("given_principal_shift", (0.0, 0.0))
        wrong = calibration.Correction(scale, (float(shift[0]), float(shift[1])), args.size)
        rows = []
        for seed in args.seeds:
            cfg = SynthConfig(
                seed=seed, frames=args.frames, width=args.size[0], height=args.size[1], **fields
            )
            frames = calibration.corrected(generate_scene(cfg).capture.frames, wrong)
            row = {"seed": seed, **measure(frames)}
            print(json.dumps({"variant": name, **row}), flush=True)
            rows.append(row)
        out[name] = {"synth": json.loads(text), "rows": rows}
    return out


def captures(items: list[str]) -> dict[str, Any]:
    from dcseg.config import CaptureOptions
    from dcseg.io.captures import read_capture

    out: dict[str, Any] = {}
    for item in items:
        path, _, text = item.partition("=")
        fx, fy, cx, cy = (float(v) for v in text.split(","))
        capture = read_capture(path, CaptureOptions(intrinsics=(fx, fy, cx, cy)))
        row = {"frames": len(capture.frames), **measure(capture.frames)}
        print(json.dumps({"capture": path, **row}), flush=True)
        out[path] = row
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--variant", action="append", default=[], help="NAME=JSON")
    parser.add_argument("--capture", action="append", default=[], help="PATH=fx,fy,cx,cy")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--size", type=lambda t: tuple(int(v) for v in t.split("x")),
                        default=(320, 240))  # fmt: skip
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    results = {
        "frames": args.frames,
        "size": list(args.size),
        "pose_threshold": pose_check.THRESHOLD,
        "min_shift_gain": registration.MIN_GAIN,
        "min_intrinsics_gain": calibration.MIN_GAIN,
        "captures": captures(args.capture),
        "variants": synthetic(args),
    }
    if args.out is not None:
        args.out.write_text(json.dumps(results, indent=2) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
