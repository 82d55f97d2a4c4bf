"""A run under a frame budget (issue 14 item 3): trained at the working resolution on the
keyframes, ``run.json`` records the plan, per-view outputs come back at the capture's size."""

from __future__ import annotations

import json
import logging
from dataclasses import replace
from pathlib import Path

import pytest

from dcseg.cli import main
from dcseg.config import FrameBudget, JobConfig, PipelineConfig, preset
from dcseg.io.images import read_image
from dcseg.jobs import RunInputs, evaluate_job, run_job
from dcseg.sizes import SCALED
from dcseg.stages import RECONSTRUCT, TRAIN
from worker.stages import LibraryStage

pytest.importorskip("pybullet", reason="the synthetic scene generator needs pybullet")


def tiny_config(budget: FrameBudget) -> PipelineConfig:
    cfg = preset("fast")
    return replace(
        cfg,
        reconstruct=replace(cfg.reconstruct, iterations=60, holdout=0),
        affinity=replace(cfg.affinity, iterations=60, rays=256),
        budget=budget,
    )


@pytest.fixture(scope="module")
def scene(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("budget") / "scene"
    args = ["synth", str(out), "--frames", "5", "--size", "160x120", "--noise", "clean"]
    assert main([*args, "--supersample", "1"]) == 0
    return out


@pytest.fixture(scope="module")
def run_dir(scene: Path) -> Path:
    out = scene.parent / "run"
    budget = FrameBudget(max_side=80, max_keyframes=4)
    run_job(RunInputs.from_bundle(scene), JobConfig(tiny_config(budget)), out)
    return out


def test_run_records_the_plan_and_trains_at_the_working_size(run_dir: Path) -> None:
    record = json.loads((run_dir / "run.json").read_text())
    capture = record["capture"]
    assert capture["size"] == [80, 60] and capture["output_size"] == [160, 120]
    assert capture["factor"] == 2 and capture["listed"] == 5 and capture["kept"] == 4
    assert record["counts"]["views"] == 4
    assert record["config"]["budget"]["max_side"] == 80
    views = json.loads((run_dir / "state" / "views.json").read_text())
    assert len(views["views"]) == 4


def test_run_records_the_size_rules_and_runs_the_resolved_values(run_dir: Path) -> None:
    record = json.loads((run_dir / "run.json").read_text())
    rules = record["size_rules"]
    gaussians = record["counts"]["gaussians"]
    assert rules["size"] == {"views": 4, "pixels": 80 * 60, "gaussians": gaussians}
    assert set(rules["values"]) == set(SCALED) and rules["explicit"] == []
    area = rules["values"]["assign.min_area"]
    assert area == {"preset": 1000, "value": round(1000 * 80 * 60 / (320 * 240))}
    assert rules["values"]["affinity.iterations"] == {"preset": 60, "value": 60}  # < 40 views
    config = PipelineConfig.from_dict(record["config"])  # what ran, what re-segmenting reuses
    assert config.assign.min_area == area["value"]
    assert sorted(config.rules.fixed) == sorted(SCALED)


def test_per_view_outputs_are_at_the_capture_resolution(run_dir: Path) -> None:
    record = json.loads((run_dir / "run.json").read_text())
    names = record["capture"]["frames"]
    for folder in ("masks", "labels"):
        written = sorted(p.stem for p in (run_dir / folder).glob("*.png"))
        assert written == sorted(names)
        assert read_image(run_dir / folder / f"{names[0]}.png").shape == (120, 160)


def test_evaluation_reads_native_outputs_back_at_the_working_size(
    run_dir: Path, scene: Path
) -> None:
    metrics = evaluate_job(run_dir, scene / "gt" / "points.ply")
    inline = json.loads((run_dir / "metrics.json").read_text())
    assert metrics["summary"] == inline["summary"]


def test_cli_flags_override_the_preset_budget(
    scene: Path, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO, logger="dcseg.io.captures")
    caplog.set_level(logging.INFO, logger="dcseg.cli.reconstruct")
    out = tmp_path / "rec"
    args = ["reconstruct", str(scene), "--out", str(out), "--iterations", "2", "--holdout", "0"]
    assert main([*args, "--max-side", "native", "--max-keyframes", "2"]) == 0
    capture = json.loads((out / "reconstruction.json").read_text())["capture"]
    assert capture["size"] == [160, 120] and capture["kept"] == 2
    assert capture["budget"]["max_side"] is None
    assert "training at 160x120 (160x120 / 1, native); 2 of 5 frames" in caplog.text
    report = json.loads((out / "reconstruction.json").read_text())
    assert report["size_rules"]["explicit"] == ["reconstruct.iterations"]  # --iterations wins
    assert report["config"]["iterations"] == 2
    assert "reconstruct.iterations" not in report["size_rules"]["values"]
    assert "size rules at 2 views of 19200 px: the presets' values" in caplog.text
    with pytest.raises(SystemExit, match=r"--max-keyframes \(options.budget.max_keyframes\)"):
        main([*args, "--max-keyframes", "none"])


def test_the_worker_stage_keys_include_the_budget() -> None:
    base = {"preset": "fast", "options": {}, "inputs": {"capture": "abc"}}
    changed = {**base, "options": {"budget": {"max_side": "native"}}}
    for stage in (LibraryStage(RECONSTRUCT), LibraryStage(TRAIN)):
        assert stage.key(base) != stage.key(changed)
