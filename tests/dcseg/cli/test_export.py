"""``dcseg export``: the files it prints, and unknown instances named on stderr."""

from __future__ import annotations

from pathlib import Path

import pytest

from dcseg.cli import main


def test_cli_exports_and_reports_bad_instances(
    run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    args = ["export", str(run), "--format", "spz", "--out", str(tmp_path), "--instance", "2"]
    assert main(args) == 0
    printed = capsys.readouterr().out.split()
    assert printed == [
        str(tmp_path / n) for n in ("instance_2.spz", "instances.spz.json", "frame.json")
    ]
    code = main(["export", str(run), "--format", "spz", "--out", str(tmp_path), "--instance", "9"])
    assert code == 1
    assert "instances: unknown instance id(s) [9]" in capsys.readouterr().err
