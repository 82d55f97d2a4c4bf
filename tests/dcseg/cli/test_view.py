"""``dcseg view``: a missing folder, a bad port, and serving a run until interrupted."""

from __future__ import annotations

import re
import signal
import subprocess
import sys
from pathlib import Path

import httpx
import pytest

from dcseg.cli import main
from tests.dcseg.viewer.browser import built as built
from tests.scenes.labelled import LabelledRun

pytestmark = pytest.mark.usefixtures("built")


def test_dcseg_view_exits_1_naming_a_missing_folder(tmp_path: Path, capsys):
    assert main(["view", str(tmp_path / "nope"), "--port", "0"]) == 1
    err = capsys.readouterr().err
    assert (
        err
        == f"dcseg view: {tmp_path / 'nope'}: not a folder (expected a run folder of `dcseg run`)\n"
    )


def test_dcseg_view_rejects_a_bad_port(labelled_run: LabelledRun, capsys):
    with pytest.raises(SystemExit) as raised:
        main(["view", str(labelled_run.folder), "--port", "70000"])
    assert raised.value.code == 2
    assert "port must be in 0..65535, got 70000" in capsys.readouterr().err


def test_dcseg_view_serves_until_interrupted(labelled_run: LabelledRun):
    command = [sys.executable, "-m", "dcseg", "view", str(labelled_run.folder), "--port", "0"]
    # Ctrl-C must reach the server however the tests were started: a shell without job control
    # starts background jobs with SIGINT ignored, and an ignored signal stays ignored in children
    with subprocess.Popen(
        command, stdout=subprocess.PIPE, text=True, preexec_fn=_default_sigint
    ) as process:
        try:
            assert process.stdout is not None
            line = process.stdout.readline()
            pattern = r"serving (.+) at (http://127\.0\.0\.1:\d+/) \(Ctrl-C to stop\)\n"
            found = re.fullmatch(pattern, line)
            assert found is not None, line
            assert found.group(1) == str(labelled_run.folder)
            labels = httpx.get(found.group(2) + "run/labels.json", timeout=10).json()
            assert [entry["name"] for entry in labels["labels"]] == ["wall", "floor", "box", "ball"]
            process.send_signal(signal.SIGINT)
            assert process.wait(10) == 0
        finally:
            if process.poll() is None:
                process.kill()


def _default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)
