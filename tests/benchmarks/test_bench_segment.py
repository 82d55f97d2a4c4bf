"""bench_segment's summary: tuning and held-out layouts apart, means over runs and seeds."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from benchmarks.bench_segment import (
    capture_faults,
    current_config,
    exported_labels,
    markdown,
    overridden,
    summarise,
    synth_fields,
)
from dcseg.config import JobConfig, preset
from dcseg.io.run_output import load_run
from dcseg.jobs import RunInputs, run_job
from dcseg.pipeline import segment_scene
from tests.dcseg.test_pipeline import tiny_config


def row(noise: str, layout: int, group: str, naive: float, ours: list[float]) -> dict[str, Any]:
    semantic = {"miou": naive, "macc": naive, "no_prediction": 1.0}
    return {
        "noise": noise,
        "layout": layout,
        "group": group,
        "baselines": {
            "naive_fusion": semantic,
            "vote3d_nearest": semantic,
            "vote3d_projection": semantic,
        },
        "dcseg": [
            {
                "cluster_seed": i,
                "segment_seconds": 1.0,
                "nearest": {"miou": v, "macc": v, "no_prediction": 0.5},
                "projection": {"miou": v, "macc": v, "no_prediction": 0.5},
                "instances": {"f1": 80.0, "precision": 70.0, "recall": 90.0, "mcov": 75.0},
            }
            for i, v in enumerate(ours)
        ],
    }


def test_held_out_layouts_are_summarised_apart_from_tuning_ones() -> None:
    rows = [
        row("default", 0, "tuning", 70.0, [90.0, 92.0]),
        row("default", 3, "heldout", 70.0, [80.0, 82.0]),
        row("default", 4, "heldout", 60.0, [70.0, 72.0]),
    ]
    summary = summarise(rows)
    held, tuned = summary["default"]["heldout"], summary["default"]["tuning"]
    assert tuned["dcseg_nearest"]["mean"] == 91.0 and tuned["layouts"] == [0]
    assert held["dcseg_nearest"]["mean"] == 76.0 and held["dcseg_nearest"]["n"] == 4
    assert held["naive_fusion"]["mean"] == 65.0 and held["naive_fusion"]["n"] == 2
    assert held["margins"]["nearest_minus_naive"]["mean"] == 11.0  # per run: 11 and 11
    assert held["dcseg_nearest"]["std"] == pytest.approx(
        5.89, abs=0.01
    )  # sample std of 80, 82, 70, 72
    table = markdown(summary)
    assert "| default | heldout 3,4 | 65.0 ± 7.1 |" in table
    assert "| default | tuning 0 |" in table


def test_overrides_reach_the_named_section() -> None:
    cfg = overridden(preset("fast"), ["assign.complete=false", "scale=0.5"])
    assert cfg.assign.complete is False and cfg.scale == 0.5


def test_synth_fields_parse_faults_and_refuse_what_the_layout_sets() -> None:
    fields = synth_fields(["pose_error_deg=0.5", "motion_blur_px=3", "depth_sigma=null"])
    assert fields == {"pose_error_deg": 0.5, "motion_blur_px": 3, "depth_sigma": None}
    with pytest.raises(SystemExit, match="--synth seed"):
        synth_fields(["seed=4"])


def test_capture_faults_read_from_scene_json(tmp_path: Path) -> None:
    made = {"noise_level": {"depth_sigma": 0.003}, "pose_error": {"deg": 0.5, "m": 0.01}}
    (tmp_path / "scene.json").write_text(json.dumps({**made, "motion_blur_px": 3}))
    faults = capture_faults(tmp_path / "scene.json")
    assert faults == {**made["noise_level"], "pose_error": made["pose_error"], "motion_blur_px": 3}
    (tmp_path / "scene.json").write_text(json.dumps({"noise_level": {"depth_sigma": 0.0}}))
    older = capture_faults(tmp_path / "scene.json")
    assert older["pose_error"] == {"deg": 0.0, "m": 0.0} and older["motion_blur_px"] == 0.0


def test_error_generators_are_summarised_like_noise_levels() -> None:
    rows = [
        row("detector", 7, "heldout", 40.0, [50.0, 52.0]),
        row("lowres", 7, "heldout", 30.0, [33.0]),
    ]
    summary = summarise(rows)
    assert summary["detector"]["heldout"]["dcseg_nearest"]["mean"] == 51.0
    assert summary["lowres"]["heldout"]["margins"]["nearest_minus_naive"]["mean"] == 3.0
    assert "| lowres | heldout 7 |" in markdown(summary)
    with pytest.raises(SystemExit, match="--synth error_model"):
        synth_fields(["error_model=detector"])


def test_exported_labels_read_back_what_the_segmentation_made(tmp_path: Path) -> None:
    """Scoring re-segments a saved run and reads the exports back as users do (with the run's
    record beside them: ``load_labels`` reads its lens record)."""
    from dcseg.cli import main

    scene = tmp_path / "scene"
    assert main(["synth", str(scene), "--frames", "4", "--size", "64x48", "--noise", "clean"]) == 0
    run_job(RunInputs.from_bundle(scene), JobConfig(tiny_config()), tmp_path / "run")
    saved = load_run(tmp_path / "run")
    names = saved.vocabulary.names
    cfg = current_config(saved, 0)
    seg = segment_scene(saved.trained, saved.semantic, len(names), cfg, class_names=names)
    (tmp_path / "out").mkdir()
    labels = exported_labels(saved, seg, tmp_path / "out")
    assert (labels.semantic_ids == seg.semantic_ids).all()
    assert set(labels.label_maps) == {v.name for v in saved.trained.views}
