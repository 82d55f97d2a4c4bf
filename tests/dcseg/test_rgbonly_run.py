"""A ``dcseg synth`` scene written as an RGB-only COLMAP model (images + sparse points, no depth)
runs end to end (issue 39, done-when): reconstruct, train, segment, evaluate."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from dcseg.cli import main
from dcseg.config import JobConfig, preset
from dcseg.io.captures import read_capture
from dcseg.io.captures.colmap_write import sample_sparse_points, write_colmap_rgb_only
from dcseg.jobs import RunInputs, run_job

pytest.importorskip("pybullet", reason="the synthetic scene generator needs pybullet")


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("rgbonly")
    scene = root / "scene"
    args = ["synth", str(scene), "--frames", "6", "--size", "160x120", "--noise", "clean"]
    assert main([*args, "--supersample", "1"]) == 0
    capture = read_capture(scene)
    colmap = write_colmap_rgb_only(capture, sample_sparse_points(capture, 3000), root / "colmap")
    cfg = preset("fast")
    cfg = replace(
        cfg,
        reconstruct=replace(cfg.reconstruct, iterations=150, holdout=3),
        affinity=replace(cfg.affinity, iterations=60, rays=256),
    )
    inputs = RunInputs(
        capture=colmap,
        agnostic_masks=scene / "masks" / "agnostic",
        semantic_masks=scene / "masks" / "semantic",
        vocabulary=scene / "vocabulary.txt",
        ground_truth=scene / "gt" / "points.ply",
    )
    run_job(inputs, JobConfig(cfg), root / "run")
    return root / "run"


def test_rgb_only_capture_runs_end_to_end(run_dir: Path) -> None:
    record = json.loads((run_dir / "run.json").read_text())
    rec = record["reconstruction"]
    assert rec["psnr"] is not None and rec["psnr"] > 15.0
    assert rec["depth_mae"] is None and rec["sensor"]["depth"]["present"] is False
    assert rec["initial_gaussians"] == 3000
    summary = record["metrics_summary"]
    assert summary["dcseg_projection"]["miou"] > 0.2
    assert summary["instances"]["f1"] > 0.0  # 150 + 60 steps on 6 views: a smoke floor
    assert (run_dir / "scene_labelled.ply").is_file()
    assert len(list((run_dir / "labels").glob("*.png"))) == 6


def test_state_holds_the_rendered_depth(run_dir: Path) -> None:
    """The cached views carry depth rendered from the reconstruction (mask scales and the
    projection metrics' depth test used it), not the capture's all-0 placeholder."""
    views = sorted((run_dir / "state" / "views").glob("*.npz"))
    assert len(views) == 6
    for path in views:
        with np.load(path) as data:
            assert float((data["depth"] > 0).mean()) > 0.5
