"""The options' command-line flags (:mod:`dcseg.cli._options`): a flag reaches the config, and a
refused value is named by its flag."""

from __future__ import annotations

from pathlib import Path

import pytest

from dcseg.cli import main


def test_cli_label_maps_flag_reaches_the_config(tmp_path: Path, monkeypatch):
    seen = []

    def record(args):
        from dcseg.cli._pipeline import job_config

        seen.append(job_config(args).pipeline.assign.label_maps)
        return 0

    monkeypatch.setattr("dcseg.cli.run.run", record)
    args = ["run", str(tmp_path), "--agnostic-masks", str(tmp_path), "--semantic-masks"]
    args += [str(tmp_path), "--vocabulary", str(tmp_path / "v.txt"), "--out", str(tmp_path / "o")]
    assert main(args) == 0 and main([*args, "--label-maps", "clusters"]) == 0
    assert seen == ["gaussians", "clusters"]


def test_cli_refuses_out_of_range_values_naming_the_flag(tmp_path: Path, capsys):
    args = ["run", str(tmp_path), "--agnostic-masks", str(tmp_path), "--semantic-masks"]
    args += [str(tmp_path), "--vocabulary", str(tmp_path / "v.txt"), "--out", str(tmp_path / "o")]
    with pytest.raises(SystemExit, match=r"--scale \(options.segment.scale\)"):
        main([*args, "--scale", "2"])
    with pytest.raises(SystemExit, match=r"--size \(options.capture.size.0\)"):
        main([*args, "--size", "90000x10"])
    with pytest.raises(SystemExit, match=r"--depth-trunc"):
        main([*args, "--depth-trunc", "inf"])
    with pytest.raises(SystemExit, match=r"--min-confidence \(options.capture.min_confidence\)"):
        main([*args, "--min-confidence", "3"])
