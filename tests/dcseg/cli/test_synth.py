"""``dcseg synth``: the files it writes, its size flag, and never leaving stale frames."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from dcseg.synth import VOCABULARY

pytest.importorskip("pybullet")


def test_cli_writes_layout(tmp_path: Path) -> None:
    from dcseg.cli import main
    from dcseg.io.captures import read_capture
    from dcseg.io.ground_truth import read_ground_truth

    out = tmp_path / "scene"
    assert main(["synth", str(out), "--seed", "2", "--frames", "3", "--size", "64x48"]) == 0
    stems = [f"frame_{i:04d}" for i in range(3)]
    for stem in stems:
        for rel in (
            f"rgb/{stem}.png",
            f"depth/{stem}.png",
            f"masks/agnostic/{stem}.json",
            f"masks/semantic/{stem}.png",
            f"gt/semantic/{stem}.png",
            f"gt/instance/{stem}.png",
        ):
            assert (out / rel).is_file(), rel
    assert (out / "vocabulary.txt").read_text().split() == list(VOCABULARY)
    summary = json.loads((out / "scene.json").read_text())
    assert summary["seed"] == 2 and summary["frames"] == 3 and summary["size"] == [64, 48]
    assert {"id", "class", "mesh", "position"} <= set(summary["instances"][0])
    assert len(read_capture(out)) == 3
    gt = read_ground_truth(out / "gt" / "points.ply", len(VOCABULARY))
    assert len(gt.labels) == summary["gt_points"] and gt.labels.min() >= 0


def test_cli_rejects_bad_size(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    from dcseg.cli import main

    with pytest.raises(SystemExit):
        main(["synth", str(tmp_path), "--size", "big"])
    assert "size must look like" in capsys.readouterr().err


def test_cli_never_leaves_stale_frames(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from dcseg.cli import main

    out = tmp_path / "scene"
    args = ["synth", str(out), "--frames", "3", "--size", "32x24"]
    assert main(args) == 0
    assert main([*args[:3], "2", *args[4:]]) == 2
    assert "--overwrite" in capsys.readouterr().err
    assert main([*args[:3], "2", *args[4:], "--overwrite"]) == 0
    assert sorted(p.stem for p in (out / "rgb").iterdir()) == ["frame_0000", "frame_0001"]
    other = tmp_path / "mine"
    other.mkdir()
    (other / "notes.txt").write_text("keep me")
    assert main(["synth", str(other), "--overwrite", "--frames", "2", "--size", "32x24"]) == 2
    assert "not a synth output" in capsys.readouterr().err
    assert (other / "notes.txt").read_text() == "keep me"
