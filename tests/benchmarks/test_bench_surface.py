"""bench_surface: centre-to-surface distance and coverage gap of a run against a synth scene."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch

from benchmarks.bench_surface import measure
from dcseg.io.ground_truth import write_ground_truth_ply
from dcseg.io.ply import write_gaussians_ply
from dcseg.types import GroundTruth
from tests.scenes.gaussians import gaussians_at


def _floor(step: float = 0.02) -> np.ndarray:
    """True surface: points on the 1 m x 1 m square z = 0, ``step`` apart."""
    xs = np.arange(0.0, 1.0 + 1e-9, step)
    x, y = np.meshgrid(xs, xs)
    return np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)


def _write(tmp_path: Path) -> tuple[Path, Path]:
    """A run whose opaque Gaussians cover the floor's left half 5 mm above it, with
    transparent ones over the right half, and the scene's ground truth."""
    surface = _floor()
    left = surface[surface[:, 0] <= 0.5] + [0.0, 0.0, 0.005]
    right = surface[surface[:, 0] > 0.5] + [0.0, 0.0, 0.005]
    means = torch.tensor(np.concatenate([left, right]), dtype=torch.float64)
    logits = torch.cat([torch.full((len(left),), 5.0), torch.full((len(right),), -5.0)])
    run, scene = tmp_path / "run", tmp_path / "scene"
    (scene / "gt").mkdir(parents=True)
    run.mkdir()
    scales = torch.full((len(means), 3), -4.0, dtype=torch.float64)
    write_gaussians_ply(run / "scene.ply", gaussians_at(means, scales, logits.double()))
    labels = np.zeros(len(surface), dtype=np.int64)
    write_ground_truth_ply(scene / "gt" / "points.ply", GroundTruth(surface, labels))
    record = {"psnr": 25.5, "depth_mae": 0.018, "surface_depth_mae": 0.017}
    (run / "reconstruction.json").write_text(json.dumps(record), encoding="utf-8")
    return run, scene


def test_distances_count_only_opaque_centres_and_the_gap_the_uncovered_half(
    tmp_path: Path,
) -> None:
    run, scene = _write(tmp_path)
    row = measure(run, scene)
    assert row["opaque"] == 26 * 51  # x in 0..0.5 (26 columns) x 51 rows
    assert abs(row["median"] - 0.005) < 1e-6 and row["within_1cm"] == 1.0
    # surface points farther than 5 cm from x = 0.5 have no opaque centre within 5 cm
    surface = _floor()
    beyond = np.hypot(surface[:, 0] - 0.5, 0.005) > 0.05
    expected = float((beyond & (surface[:, 0] > 0.5)).mean())
    assert abs(row["coverage_gap"] - expected) < 1e-9 and 0.4 < expected < 0.5
    assert (row["psnr"], row["depth_mae"]) == (25.5, 0.018)
