"""One composition of stage 1: the CLI verb and the worker both run the reconstruct stage
(:data:`dcseg.stages.RECONSTRUCT`, as ``dcseg run`` does), which calls
:func:`dcseg.reconstruct.job.reconstruct_scene` with the device and the config the one builder
made."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

import dcseg.io.captures
import dcseg.reconstruct.job as job
from dcseg.cli import main
from dcseg.config import FrameBudget
from dcseg.errors import InputError
from dcseg.io.captures.plan import CaptureMeta, plan_capture
from dcseg.stages import RECONSTRUCT
from jobstore.settings import Settings
from tests.scenes.analytic import make_capture
from worker.stage import StageContext
from worker.stages import LibraryStage


class Reached(Exception):
    """The fake reconstruction was called."""


@pytest.fixture
def calls(monkeypatch: pytest.MonkeyPatch) -> list[tuple[Any, ...]]:
    seen: list[tuple[Any, ...]] = []

    def fake(capture: Any, cfg: Any, device: torch.device, on_progress: Any = None) -> Any:
        seen.append((len(capture), cfg.iterations, device.type))
        raise Reached

    def read_planned(path: Path, options: Any, budget: FrameBudget) -> Any:
        seen.append(("read", budget.max_side))
        capture = make_capture(3)
        poses = np.stack([f.c2w for f in capture.frames])
        size = (capture.frames[0].width, capture.frames[0].height)
        return capture, plan_capture(CaptureMeta(capture.names, poses, size), budget)

    monkeypatch.setattr(job, "reconstruct_scene", fake)
    monkeypatch.setattr(dcseg.io.captures, "read_planned", read_planned)
    return seen


def test_cli_reconstruct_runs_the_reconstruct_stage(calls, tmp_path: Path) -> None:
    argv = ["reconstruct", str(tmp_path), "--out", str(tmp_path / "o"), "--iterations", "9"]
    with pytest.raises(Reached):
        main([*argv, "--device", "cpu"])
    assert calls == [("read", 640), (3, 9, "cpu")]


def test_worker_runs_the_same_reconstruct_stage(calls, tmp_path: Path) -> None:
    options = {"reconstruct": {"iterations": 11}, "budget": {"max_side": "native"}}
    config = {"preset": "fast", "options": options}
    ctx = StageContext(
        "job", tmp_path, config, Settings(device="cpu"), lambda s, f, m: None, lambda m: None
    )
    with pytest.raises(Reached):
        LibraryStage(RECONSTRUCT).run(ctx, tmp_path / "out")
    assert calls == [("read", None), (3, 11, "cpu")]


def test_unknown_device_is_an_input_error_naming_it(calls, tmp_path: Path, capsys) -> None:
    argv = ["reconstruct", str(tmp_path), "--out", str(tmp_path / "o"), "--device", "tpu:0"]
    assert main(argv) == 1
    assert "device: unknown device 'tpu:0'" in capsys.readouterr().err
    with pytest.raises(InputError, match="unknown device"):
        job.device_of("gpu")
    assert calls == []
