"""``dcseg reconstruct`` writes a loadable PLY and a report."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import dcseg.io.captures
from dcseg.cli import main
from dcseg.cli._pipeline import job_config
from dcseg.config import BUDGET_PRESETS, CaptureOptions, FrameBudget
from dcseg.io.captures.plan import CaptureMeta, plan_capture
from dcseg.io.ground_truth import write_ground_truth_ply
from dcseg.io.ply import read_gaussians_ply
from dcseg.io.poses import read_poses
from dcseg.reconstruct.config import REFINE_POSES, SURFACE_PRIORS
from dcseg.reconstruct.init import backproject
from dcseg.types import GroundTruth
from tests.scenes.analytic import make_capture


def planned_reader(seen: list[CaptureOptions], budgets: list[FrameBudget]) -> Any:
    """A stand-in for ``read_planned``: a 5-view analytic capture; records its arguments."""

    def fake_read_planned(path: Path, options: CaptureOptions, budget: FrameBudget) -> Any:
        seen.append(options)
        budgets.append(budget)
        capture = make_capture(5, 24, 18)
        poses = np.stack([f.c2w for f in capture.frames])
        return capture, plan_capture(CaptureMeta(capture.names, poses, (24, 18)), budget)

    return fake_read_planned


def test_reconstruct_writes_ply_and_report(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    seen: list[CaptureOptions] = []
    budgets: list[FrameBudget] = []
    monkeypatch.setattr(dcseg.io.captures, "read_planned", planned_reader(seen, budgets))
    out = tmp_path / "out"
    argv = ["reconstruct", str(tmp_path), "--out", str(out), "--iterations", "8"]
    argv += ["--holdout", "3", "--seed", "1", "--intrinsics", "10,10,5,5", "--stride", "2"]
    assert main(argv) == 0
    assert seen[0].intrinsics == (10.0, 10.0, 5.0, 5.0) and seen[0].stride == 2
    assert budgets == [BUDGET_PRESETS["fast"]]
    gaussians = read_gaussians_ply(out / "scene.ply")
    report = json.loads((out / "reconstruction.json").read_text())
    assert report["gaussians"] == len(gaussians) > 0
    assert report["test_frames"] == ["frame000", "frame003"]
    assert [v["name"] for v in report["views"]] == report["test_frames"]
    assert report["psnr"] > 0 and report["depth_mae"] >= 0
    assert 0.0 < report["observed_share"] <= 1.0 and report["psnr_observed"] > 0
    assert all(0.0 < v["observed_share"] <= 1.0 for v in report["views"])
    assert set(report["seconds"]) == {
        "read", "registration", "init", "sensor", "train", "eval", "write"
    }  # fmt: skip
    assert report["config"]["iterations"] == 8 and report["seed"] == 1
    # discs pulled onto the surfaces after densification by default; tight surfaces opt-in
    assert report["config"]["centre_weight"] == 10.0 and report["config"]["init_thickness"] == 0.1
    assert report["config"]["centre_from"] is None and report["config"]["planar_depth"] is False
    assert report["config"]["depth_filter_window"] == 5
    # 24 x 18 depth maps hold too few whole windows to measure noise on (then None)
    assert report["depth_noise_at_1m"] is None or report["depth_noise_at_1m"] >= 0.0
    sensor = report["sensor"]  # what was detected and applied
    assert sensor["depth"]["noise"]["a_at_1m"] == report["depth_noise_at_1m"]
    assert 0.0 <= sensor["depth"]["missing_fraction"] <= 1.0
    assert set(sensor) == {
        "frames_measured", "depth", "exposure", "poses", "motion_blur", "registration",
        "intrinsics",
    }  # fmt: skip
    assert sensor["registration"]["mode"] == "auto" and "refined" in sensor["poses"]
    assert "geometry" not in report  # no ground truth beside the capture
    assert report["backend"] == "cpu"
    assert report["peak_memory_mb"] > 0 and "torch" in report["versions"]
    assert report["capture"]["size"] == [24, 18] and report["capture"]["factor"] == 1
    assert "reconstruct" in capsys.readouterr().err  # the progress bar


def test_a_bundles_ground_truth_adds_geometry_metrics(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(dcseg.io.captures, "read_planned", planned_reader([], []))
    frames = make_capture(5, 24, 18).frames
    surface = np.concatenate([backproject(f)[0] for f in frames])  # points on the surfaces
    gt = GroundTruth(surface, np.zeros(len(surface), np.int64))
    write_ground_truth_ply(tmp_path / "gt" / "points.ply", gt)
    out = tmp_path / "out"
    argv = ["reconstruct", str(tmp_path), "--out", str(out), "--iterations", "8"]
    assert main(argv + ["--holdout", "3", "--intrinsics", "10,10,5,5"]) == 0
    report = json.loads((out / "reconstruction.json").read_text())
    geometry = report["geometry"]
    assert geometry["surface_points"] == len(surface)
    assert geometry["ground_truth"] == str(tmp_path / "gt" / "points.ply")
    assert 0.0 <= geometry["coverage"]["gap"] <= 1.0
    assert set(geometry["centre_to_surface"]) >= {"opaque", "median", "p90", "within_1cm"}
    assert "geometry" in report["seconds"]


def test_reconstruct_reports_input_errors(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code = main(["reconstruct", str(tmp_path / "missing"), "--out", str(tmp_path / "o")])
    assert code == 1
    assert "missing" in capsys.readouterr().err


def test_surface_priors_flag_sets_the_priors(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(dcseg.io.captures, "read_planned", planned_reader([], []))
    out = tmp_path / "out"
    argv = ["reconstruct", str(tmp_path), "--out", str(out), "--iterations", "4"]
    assert main([*argv, "--surface-priors"]) == 0
    config = json.loads((out / "reconstruction.json").read_text())["config"]
    assert {k: config[k] for k in SURFACE_PRIORS} == SURFACE_PRIORS


def test_run_flag_puts_the_priors_in_the_job_config() -> None:
    from dcseg.cli import build_parser

    run = ["run", "cap", "--out", "o", "--agnostic-masks", "a", "--semantic-masks", "s"]
    run += ["--vocabulary", "v"]
    cfg = job_config(build_parser().parse_args([*run, "--surface-priors"])).pipeline
    assert cfg.reconstruct.centre_from == SURFACE_PRIORS["centre_from"] == 0
    assert cfg.reconstruct.pull_start == 0
    assert cfg.reconstruct.planar_depth is True
    plain = job_config(build_parser().parse_args(run)).pipeline
    assert plain.reconstruct.centre_from is None and plain.reconstruct.planar_depth is False
    assert plain.reconstruct.pull_start == plain.reconstruct.densify_until == 1200


def test_refine_poses_flag_refines_and_reports_the_poses(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(dcseg.io.captures, "read_planned", planned_reader([], []))
    out = tmp_path / "out"
    argv = ["reconstruct", str(tmp_path), "--out", str(out), "--iterations", "4"]
    assert main([*argv, "--refine-poses"]) == 0
    report = json.loads((out / "reconstruction.json").read_text())
    assert {k: report["config"][k] for k in REFINE_POSES} == REFINE_POSES
    assert report["pose_refinement"]["file"] == "poses.json"
    assert "poses" not in report["pose_refinement"]
    poses = read_poses(out / "poses.json")
    assert sorted(poses) == sorted(report["train_frames"] + report["test_frames"])
    plain = tmp_path / "plain"
    assert main(["reconstruct", str(tmp_path), "--out", str(plain), "--iterations", "4"]) == 0
    report = json.loads((plain / "reconstruction.json").read_text())
    assert report["config"]["pose_refinement"] == "auto" and report["pose_refinement"] is None
    assert report["sensor"]["poses"]["mode"] == "auto"
    assert report["sensor"]["poses"]["refined"] is False
    assert not (plain / "poses.json").exists()


def test_reconstruct_refuses_a_non_empty_out_and_overwrite_drops_stale_poses(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr(dcseg.io.captures, "read_planned", planned_reader([], []))
    out = tmp_path / "out"
    argv = ["reconstruct", str(tmp_path), "--out", str(out), "--iterations", "4"]
    assert main([*argv, "--refine-poses"]) == 0
    before = (out / "scene.ply").read_bytes()
    capsys.readouterr()
    assert main(argv) == 2
    assert f"{out} is not empty; pass --overwrite" in capsys.readouterr().err
    assert (out / "scene.ply").read_bytes() == before and (out / "poses.json").is_file()
    assert main([*argv, "--overwrite"]) == 0
    report = json.loads((out / "reconstruction.json").read_text())
    assert report["pose_refinement"] is None
    assert not (out / "poses.json").exists()  # it belonged to the refined scene


def test_run_flag_puts_pose_refinement_in_the_job_config() -> None:
    from dcseg.cli import build_parser
    from dcseg.cli._pipeline import reconstruct_fields

    run = ["run", "cap", "--out", "o", "--agnostic-masks", "a", "--semantic-masks", "s"]
    run += ["--vocabulary", "v", "--refine-poses"]
    cfg = job_config(build_parser().parse_args(run)).pipeline
    assert cfg.reconstruct.pose_refinement == REFINE_POSES["pose_refinement"] == "on"
    argv = ["reconstruct", "cap", "--out", "o", "--pose-refinement", "off"]
    assert reconstruct_fields(build_parser().parse_args(argv)) == {"pose_refinement": "off"}
    argv[-1] = "sometimes"
    with pytest.raises(SystemExit):
        build_parser().parse_args(argv)
