"""A capture given with wrong intrinsics: the reconstruction corrects them, poses.json keeps the
correction, and the later stages (and a run given that scene) see the corrected cameras."""

from __future__ import annotations

import json
import logging
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from dcseg.cli import main
from dcseg.config import JobConfig, PipelineConfig, preset
from dcseg.errors import InputError
from dcseg.export.depth import depth_views
from dcseg.io.poses import read_cameras
from dcseg.jobs import RunInputs, run_job

pytest.importorskip("pybullet", reason="the synthetic scene generator needs pybullet")

SCALE = 1.1
"""The given focal lengths are this many times the true ones."""


def tiny_config() -> PipelineConfig:
    cfg = preset("fast")
    return replace(
        cfg,
        reconstruct=replace(cfg.reconstruct, iterations=40, holdout=4, pose_refinement="off"),
        affinity=replace(cfg.affinity, iterations=20, rays=256),
    )


@pytest.fixture(scope="module")
def scene(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A synthetic capture whose capture.json states focal lengths 10 % too long."""
    out = tmp_path_factory.mktemp("intrinsics") / "scene"
    args = ["synth", str(out), "--frames", "16", "--size", "128x96", "--noise", "clean"]
    assert main([*args, "--supersample", "1"]) == 0
    manifest = json.loads((out / "capture.json").read_text())
    manifest["true_intrinsics"] = dict(manifest["intrinsics"])
    for key in ("fx", "fy"):
        manifest["intrinsics"][key] *= SCALE
    (out / "capture.json").write_text(json.dumps(manifest))
    return out


def _true_K(scene: Path) -> np.ndarray:
    k = json.loads((scene / "capture.json").read_text())["true_intrinsics"]
    return np.array([[k["fx"], 0, k["cx"]], [0, k["fy"], k["cy"]], [0, 0, 1]])


@pytest.fixture(scope="module")
def run(scene: Path) -> Path:
    out = scene.parent / "run"
    run_job(RunInputs.from_bundle(scene), JobConfig(tiny_config()), out)
    return out


def test_the_later_stages_render_with_the_corrected_intrinsics(scene: Path, run: Path) -> None:
    record = json.loads((run / "run.json").read_text())
    entry = record["reconstruction"]["sensor"]["intrinsics"]
    assert entry["applied"]["focal_scale"] == pytest.approx(1 / SCALE, abs=0.01)
    views = json.loads((run / "state" / "views.json").read_text())["views"]
    for view in views:
        np.testing.assert_allclose(view["K"], _true_K(scene), rtol=0.012, atol=1.0)


def test_depth_read_from_the_capture_sees_the_run_cameras(scene: Path, run: Path) -> None:
    """Meshing from the capture (``dcseg export --capture``) reads it as the run did and
    through the run's ``poses.json``: the corrected intrinsics, not the capture's."""
    assert (run / "state" / "poses.json").is_file()
    record = json.loads((run / "run.json").read_text())
    assert record["capture_options"]["stride"] == 1
    views = depth_views(run, scene)
    assert len(views) == 16
    for view in views:
        np.testing.assert_allclose(view.K, _true_K(scene), rtol=0.012, atol=1.0)


@pytest.fixture(scope="module")
def reconstructed(scene: Path) -> Path:
    """``dcseg reconstruct`` output (tiny): scene.ply and poses.json with the correction."""
    out = scene.parent / "reconstructed"
    argv = ["reconstruct", str(scene), "--out", str(out), "--iterations", "30"]
    assert main([*argv, "--pose-refinement", "off"]) == 0
    return out


def test_a_given_scene_brings_its_corrected_intrinsics(scene: Path, reconstructed: Path) -> None:
    cameras = read_cameras(reconstructed / "poses.json")
    report = json.loads((reconstructed / "reconstruction.json").read_text())
    assert cameras.intrinsics == report["sensor"]["intrinsics"]["applied"]
    assert cameras.registration is None and len(cameras.poses) == 16
    out = scene.parent / "given"
    inputs = RunInputs.from_bundle(scene, scene=reconstructed / "scene.ply")
    run_job(inputs, JobConfig(tiny_config()), out)
    for view in json.loads((out / "state" / "views.json").read_text())["views"]:
        np.testing.assert_allclose(view["K"], _true_K(scene), rtol=0.012, atol=1.0)


def test_a_given_scene_keeps_its_cameras_when_the_capture_states_other_intrinsics(
    scene: Path, reconstructed: Path, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """Given the scene, a capture now stating the true intrinsics is not corrected again: the
    correction records what it was measured from (``given``) and brings the scene's cameras."""
    cameras = read_cameras(reconstructed / "poses.json")
    assert cameras.intrinsics is not None and len(cameras.intrinsics["given"]) == 4
    copy = Path(shutil.copytree(scene, tmp_path / "scene"))
    manifest = json.loads((copy / "capture.json").read_text())
    manifest["intrinsics"] = dict(manifest["true_intrinsics"])
    (copy / "capture.json").write_text(json.dumps(manifest))
    inputs = RunInputs.from_bundle(copy, scene=reconstructed / "scene.ply")
    with caplog.at_level(logging.WARNING, logger="dcseg.reconstruct.poses"):
        run_job(inputs, JobConfig(tiny_config()), tmp_path / "out")
    for view in json.loads((tmp_path / "out" / "state" / "views.json").read_text())["views"]:
        np.testing.assert_allclose(view["K"], _true_K(scene), rtol=0.012, atol=1.0)
    assert "capture now states others" in caplog.text


@pytest.mark.parametrize(
    ("record", "message"),
    [
        ({"focal_scale": "x", "principal_shift_px": [0, 0], "at_size": [1, 1]}, '"focal_scale"'),
        ({"focal_scale": 0.9, "principal_shift_px": [0], "at_size": [1, 1]}, "principal_shift"),
        ([0.9], "must be an object"),
    ],
)
def test_a_bad_intrinsics_record_is_named_and_refused(
    scene: Path, reconstructed: Path, tmp_path: Path, record: object, message: str
) -> None:
    copy = tmp_path / "scene"
    copy.mkdir()
    (copy / "scene.ply").write_bytes((reconstructed / "scene.ply").read_bytes())
    doc = json.loads((reconstructed / "poses.json").read_text())
    (copy / "poses.json").write_text(json.dumps({**doc, "intrinsics": record}))
    inputs = RunInputs.from_bundle(scene, scene=copy / "scene.ply")
    with pytest.raises(InputError) as caught:
        run_job(inputs, JobConfig(tiny_config()), tmp_path / "out")
    text = str(caught.value)
    assert str(copy / "poses.json") in text and '"intrinsics"' in text and message in text
