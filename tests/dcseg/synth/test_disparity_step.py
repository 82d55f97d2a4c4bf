"""``dcseg synth --disparity-step``: depth quantised in disparity, as Kinect v1 writes it."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from dcseg.cli import main
from dcseg.reconstruct.depth_noise import disparity_step
from dcseg.synth import SynthConfig, generate_scene, write_scene
from dcseg.synth.noise import disparity_quantised

KINECT = 0.0029


def test_quantised_depth_lies_on_a_lattice_in_inverse_depth() -> None:
    ramp = np.linspace(0.6, 3.5, 5000)
    out = disparity_quantised(np.concatenate([ramp, [0.0]]), KINECT)
    assert out[-1] == 0.0  # invalid stays invalid
    levels = np.unique(1.0 / out[:-1])
    assert np.allclose(np.diff(levels), KINECT, rtol=1e-6)
    assert np.abs(out[:-1] - ramp).max() <= 0.5 * KINECT * 3.5**2 * 1.01  # half a step at most
    steps = np.diff(np.unique(out[:-1]))
    assert steps.min() == pytest.approx(KINECT * 0.6**2, rel=0.02)  # steps grow with z^2
    assert steps.max() == pytest.approx(KINECT * 3.5**2, rel=0.02)


pybullet = pytest.importorskip("pybullet", reason="the synthetic scene generator needs pybullet")


def test_the_written_depth_steps_grow_with_the_squared_depth(tmp_path: Path) -> None:
    cfg = SynthConfig(seed=1, frames=2, width=160, height=120, disparity_step=KINECT)
    write_scene(generate_scene(cfg), tmp_path / "scene")
    path = sorted((tmp_path / "scene" / "depth").glob("*.png"))[0]
    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)  # read by OpenCV, not by dcseg
    assert raw is not None and raw.dtype == np.uint16  # millimetres
    depth = raw.astype(np.float64) / 1000.0
    distinct = np.unique(depth[depth > 0])
    gaps, at = np.diff(distinct), distinct[1:]
    wide = gaps > 0.004  # steps past the millimetre rounding: between adjacent levels
    adjacent = wide & (gaps < 1.5 * KINECT * at**2)
    assert adjacent.sum() >= 10
    assert np.allclose(gaps[adjacent], KINECT * at[adjacent] ** 2, atol=0.0011, rtol=0.05)
    assert disparity_step(depth) == pytest.approx(KINECT, rel=0.01)
    plain = generate_scene(SynthConfig(seed=1, frames=2, width=160, height=120))
    assert disparity_step(plain.capture.frames[0].depth) == 0.0


def test_the_step_is_validated(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="disparity_step must be between 0 and 0.02"):
        SynthConfig(disparity_step=0.5)
    code = main(["synth", str(tmp_path / "s"), "--disparity-step", "-1"])
    assert code == 2
    assert (
        "disparity_step must be between 0 and 0.02 per metre, got -1.0" in capsys.readouterr().err
    )
