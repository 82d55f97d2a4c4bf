"""A run that refines poses: the later stages use the refined poses, run.json says how far
they moved (without listing them), and a run without refinement keeps the capture's poses."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from dcseg.cli import main
from dcseg.config import JobConfig, PipelineConfig, preset
from dcseg.errors import InputError
from dcseg.export.depth import depth_views
from dcseg.io.poses import read_poses
from dcseg.jobs import RunInputs, run_job
from dcseg.reconstruct.poses import pose_change

pytest.importorskip("pybullet", reason="the synthetic scene generator needs pybullet")


def tiny_config(pose_lr: float) -> PipelineConfig:
    cfg = preset("fast")
    return replace(
        cfg,
        reconstruct=replace(
            cfg.reconstruct,
            iterations=60,
            holdout=4,
            pose_lr=pose_lr,
            pose_from=0,
            pose_align_steps=5,
            pose_refinement="on",
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
    run_job(RunInputs.from_bundle(scene), JobConfig(tiny_config(1e-3)), run)
    record = json.loads((run / "run.json").read_text())
    refinement = record["reconstruction"]["pose_refinement"]
    assert "poses" not in refinement
    assert refinement["rotation_deg"]["max"] > 0.0
    given, used = _capture_poses(scene), _state_poses(run)
    assert set(used) == set(given)
    moved = [pose_change(given[name], used[name])[0] for name in used]
    assert min(moved) > 0.0 and max(moved) == pytest.approx(refinement["rotation_deg"]["max"])
    # meshing from the capture (export --capture) uses the refined poses too
    for view in depth_views(run, scene):
        np.testing.assert_allclose(view.c2w, used[view.name], atol=1e-6)


def test_without_refinement_the_capture_poses_are_kept(scene: Path) -> None:
    run = scene.parent / "plain"
    run_job(RunInputs.from_bundle(scene), JobConfig(tiny_config(0.0)), run)
    record = json.loads((run / "run.json").read_text())
    assert record["reconstruction"]["pose_refinement"] is None
    given = _capture_poses(scene)
    for name, c2w in _state_poses(run).items():
        np.testing.assert_allclose(c2w, given[name], atol=1e-9)


@pytest.fixture(scope="module")
def refined_scene(scene: Path) -> Path:
    """``dcseg reconstruct --refine-poses`` output (tiny): scene.ply and poses.json."""
    out = scene.parent / "reconstructed"
    argv = ["reconstruct", str(scene), "--out", str(out), "--iterations", "30", "--refine-poses"]
    assert main(argv) == 0
    return out


def test_a_given_scene_brings_its_refined_poses(scene: Path, refined_scene: Path) -> None:
    run = scene.parent / "given"
    inputs = RunInputs.from_bundle(scene, scene=refined_scene / "scene.ply")
    run_job(inputs, JobConfig(tiny_config(0.0)), run)
    refined = read_poses(refined_scene / "poses.json")
    used = _state_poses(run)
    assert set(used) == set(refined)
    for name, c2w in used.items():
        np.testing.assert_allclose(c2w, refined[name], atol=1e-9)
    record = json.loads((run / "run.json").read_text())
    assert record["reconstruction"]["pose_refinement"]["poses_from"] == str(refined_scene)


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("{not json", "cannot be read as JSON"),
        ('{"format": "other"}', "is not a poses file"),
        ('{"format": "dcseg-poses", "poses": {"frame_0000": [[1, 0], [0, 1]]}}', "4x4"),
        ('{"format": "dcseg-poses", "poses": {"frame_0000": ' + str(np.eye(4).tolist()) + "}}",
         "none for 4 of the capture's frames"),
    ],
)  # fmt: skip
def test_a_bad_poses_file_is_named_and_refused(
    scene: Path, refined_scene: Path, tmp_path: Path, content: str, message: str
) -> None:
    copy = tmp_path / "scene"
    copy.mkdir()
    (copy / "scene.ply").write_bytes((refined_scene / "scene.ply").read_bytes())
    (copy / "poses.json").write_text(content)
    inputs = RunInputs.from_bundle(scene, scene=copy / "scene.ply")
    with pytest.raises(InputError) as caught:
        run_job(inputs, JobConfig(tiny_config(0.0)), tmp_path / "run")
    assert str(copy / "poses.json") in str(caught.value) and message in str(caught.value)
    assert not (tmp_path / "run").exists()
