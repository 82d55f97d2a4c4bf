"""``dcseg reconstruct`` writes a loadable PLY and a report."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

import dcseg.io.captures
from dcseg.cli import main
from dcseg.config import CaptureOptions
from dcseg.io.ply import read_gaussians_ply
from tests.dcseg.reconstruct.scene import make_capture


def test_reconstruct_writes_ply_and_report(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    seen: list[CaptureOptions] = []

    def fake_read_capture(path: Path, options: CaptureOptions):
        seen.append(options)
        return make_capture(5, 24, 18)

    monkeypatch.setattr(dcseg.io.captures, "read_capture", fake_read_capture)
    out = tmp_path / "out"
    argv = ["reconstruct", str(tmp_path), "--out", str(out), "--iterations", "8"]
    argv += ["--holdout", "3", "--seed", "1", "--intrinsics", "10,10,5,5", "--stride", "2"]
    assert main(argv) == 0
    assert seen[0].intrinsics == (10.0, 10.0, 5.0, 5.0) and seen[0].stride == 2
    gaussians = read_gaussians_ply(out / "scene.ply")
    report = json.loads((out / "reconstruction.json").read_text())
    assert report["gaussians"] == len(gaussians) > 0
    assert report["test_frames"] == ["frame000", "frame003"]
    assert [v["name"] for v in report["views"]] == report["test_frames"]
    assert report["psnr"] > 0 and report["depth_mae"] >= 0
    assert set(report["seconds"]) == {"read", "init", "train", "eval", "write"}
    assert report["config"]["iterations"] == 8 and report["seed"] == 1
    assert report["backend"] == "cpu"
    assert report["peak_memory_mb"] > 0 and "torch" in report["versions"]
    assert "reconstruct" in capsys.readouterr().err  # the progress bar


def test_reconstruct_reports_input_errors(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code = main(["reconstruct", str(tmp_path / "missing"), "--out", str(tmp_path / "o")])
    assert code == 1
    assert "missing" in capsys.readouterr().err
