"""held_out_errors: saved held-out renders and the anatomy of their depth and colour errors."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import dcseg.io.captures
import dcseg.reconstruct.evaluate as evaluate
from benchmarks.held_out_errors import RENDER, main, summarise
from tests.dcseg.cli.test_reconstruct import planned_reader


def _save(path: Path, offset: float, shift: int) -> None:
    """A 2 m wall with a 1 m box in its middle; the render's depth is ``offset`` too far
    everywhere and its colour the image's moved ``shift`` px right."""
    truth = np.full((40, 60), 2.0, dtype=np.float32)
    truth[10:30, 20:40] = 1.0
    truth[0, :] = 0.0  # no depth: not scored
    image = np.random.default_rng(0).uniform(size=(40, 60, 3)).astype(np.float32)
    render = np.roll(image, shift, axis=1)
    np.savez_compressed(path, depth=truth + offset, truth=truth, render=render, image=image)


def test_summary_splits_the_error_and_finds_a_whole_image_shift(tmp_path: Path) -> None:
    _save(tmp_path / "a.npz", 0.01, 2)
    _save(tmp_path / "b.npz", 0.3, 0)
    report = summarise(tmp_path)
    assert report["views"] == 2 and report["depth_pixels"] == 2 * 39 * 60
    assert report["depth_mae_mm"] == pytest.approx(155.0, abs=0.01)
    assert report["tails"][">0.2 m"]["share"] == pytest.approx(0.5)
    assert report["tails"][">0.2 m"]["contribution_mm"] == pytest.approx(150.0, abs=0.01)
    assert 0.0 < report["edge_share"] < 0.3  # the box's outline, not the flat faces
    a, b = report["per_view"]
    assert a["colour_shift_px"] == [2, 0] and a["shifted_psnr"] > a["psnr"] + 10
    assert b["colour_shift_px"] == [0, 0] and b["shifted_psnr"] == b["psnr"]
    assert a["depth_mae_mm"] == pytest.approx(10.0, abs=0.01)
    assert set(report["by_sensor_depth"]) == {"1-2 m", "2-3 m"}


def test_summarise_writes_a_named_entry_and_refuses_an_empty_folder(tmp_path: Path) -> None:
    _save(tmp_path / "a.npz", 0.01, 0)
    out = tmp_path / "results.json"
    assert main(["summarise", str(tmp_path), "--out", str(out), "--name", "wall"]) == 0
    assert json.loads(out.read_text())["wall"]["depth_mae_mm"] == pytest.approx(10.0, abs=0.01)
    (tmp_path / "empty").mkdir()
    with pytest.raises(SystemExit, match="no saved held-out views"):
        summarise(tmp_path / "empty")


def test_run_saves_every_held_out_view(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(dcseg.io.captures, "read_planned", planned_reader([], []))
    dump, out = tmp_path / "dump", tmp_path / "out"
    argv = [str(tmp_path), "--out", str(out), "--iterations", "8", "--holdout", "3"]
    assert main(["run", str(dump), "--", *argv, "--intrinsics", "10,10,5,5"]) == 0
    report = json.loads((out / "reconstruction.json").read_text())
    assert sorted(p.stem for p in dump.glob("*.npz")) == report["test_frames"]
    saved = np.load(dump / f"{report['test_frames'][0]}.npz")
    assert saved["depth"].shape == saved["truth"].shape == saved["neighbour"].shape == (18, 24)
    assert saved["render"].shape == saved["image"].shape == (18, 24, 3)
    summary = summarise(dump)
    assert summary["neighbour_depth"] is not None and 0 < summary["neighbour_depth"]["share"] <= 1
    assert saved["gap1"].shape == (18, 24) and summary["one_training_frame_at_gap"]["1"]["pixels"]


def test_run_saves_the_scored_render_and_restores_the_evaluation(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(dcseg.io.captures, "read_planned", planned_reader([], []))
    scored, drawn = evaluate.evaluate_view, getattr(evaluate, RENDER)
    calls: list[int] = []

    def counting(*args: Any, **kw: Any) -> Any:
        calls.append(1)
        return drawn(*args, **kw)

    monkeypatch.setattr(evaluate, RENDER, counting)
    argv = [str(tmp_path), "--out", str(tmp_path / "out"), "--iterations", "8", "--holdout", "3"]
    assert main(["run", str(tmp_path / "dump"), "--", *argv, "--intrinsics", "10,10,5,5"]) == 0
    report = json.loads((tmp_path / "out" / "reconstruction.json").read_text())
    assert len(calls) == len(report["test_frames"])  # one render per held-out view
    assert evaluate.evaluate_view is scored and getattr(evaluate, RENDER) is counting
