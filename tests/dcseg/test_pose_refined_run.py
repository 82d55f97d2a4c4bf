"""A run that refines poses: the later stages use the refined poses, run.json says how far
they moved (without listing them), and a run without refinement keeps the capture's poses."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from dcseg.cli import main
from dcseg.config import PipelineConfig, preset
from dcseg.jobs import RunInputs, run_job
from dcseg.reconstruct.poses import pose_change

pytest.importorskip("pybullet", reason="the synthetic scene generator needs pybullet")


def tiny_config(pose_lr: float) -> PipelineConfig:
    cfg = preset("fast")
    return replace(
        cfg,
        reconstruct=replace(
            cfg.reconstruct, iterations=60, holdout=4, pose_lr=pose_lr, pose_align_steps=5
        ),
        affinity=replace(cfg.affinity, iterations=40, rays=256),
    )


@pytest.fixture(scope="module")
def scene(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("poses") / "scene"
    args = ["synth", str(out), "--frames", "5", "--size", "96x72", "--noise", "clean"]
    assert main([*args, "--supersample", "1", "--pose-error-deg", "0.5"]) == 0
    return out


def _state_poses(run: Path) -> dict[str, np.ndarray]:
    views = json.loads((run / "state" / "views.json").read_text())["views"]
    return {v["name"]: np.asarray(v["c2w"]) for v in views}


def _capture_poses(scene: Path) -> dict[str, np.ndarray]:
    frames = json.loads((scene / "capture.json").read_text())["frames"]
    return {f["name"]: np.asarray(f["c2w"]) for f in frames}


def test_the_later_stages_use_the_refined_poses(scene: Path) -> None:
    run = scene.parent / "refined"
    run_job(RunInputs.from_bundle(scene), tiny_config(1e-3), run)
    record = json.loads((run / "run.json").read_text())
    refinement = record["reconstruction"]["pose_refinement"]
    assert "poses" not in refinement
    assert refinement["rotation_deg"]["max"] > 0.0
    given, used = _capture_poses(scene), _state_poses(run)
    assert set(used) == set(given)
    moved = [pose_change(given[name], used[name])[0] for name in used]
    assert min(moved) > 0.0 and max(moved) == pytest.approx(refinement["rotation_deg"]["max"])


def test_without_refinement_the_capture_poses_are_kept(scene: Path) -> None:
    run = scene.parent / "plain"
    run_job(RunInputs.from_bundle(scene), tiny_config(0.0), run)
    record = json.loads((run / "run.json").read_text())
    assert record["reconstruction"]["pose_refinement"] is None
    given = _capture_poses(scene)
    for name, c2w in _state_poses(run).items():
        np.testing.assert_allclose(c2w, given[name], atol=1e-9)
