"""The labelled run with camera poses: its ``state/`` says which world axis is up."""

from __future__ import annotations

import math
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from tests.scenes.analytic import make_capture
from tests.scenes.labelled import LabelledRun
from tests.scenes.runs import write_state

Z_TO_Y = np.array([[1.0, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1]])
"""Turns the analytic capture's z-up poses into a y-up world (+z goes to +y)."""


def tilt_about_x(degrees: float) -> NDArray[np.float64]:
    """``[4, 4]`` rotation by ``degrees`` about x (+z goes towards -y)."""
    c, s = math.cos(math.radians(degrees)), math.sin(math.radians(degrees))
    return np.array([[1.0, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1]])


def run_with_poses(labelled_run: LabelledRun, folder: Path, turn: NDArray[np.float64]) -> Path:
    """A copy of the labelled run with a ``state/`` whose camera poses are the analytic
    capture's (+z up) turned by ``turn``."""
    run = Path(shutil.copytree(labelled_run.folder, folder))
    capture = make_capture()
    frames = tuple(replace(f, c2w=turn @ f.c2w) for f in capture.frames)
    write_state(run, replace(capture, frames=frames))
    return run
