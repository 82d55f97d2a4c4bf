"""Synthetic auto exposure: smooth per-frame gains of the asked spread, colour only."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from dcseg.cli import main
from dcseg.reconstruct.exposure import colour_changes
from dcseg.synth import SynthConfig, generate_scene
from dcseg.synth.exposure import exposed, frame_gains


def test_gains_have_the_asked_spread_and_drift_smoothly() -> None:
    gains = frame_gains(200, 0.2, np.random.default_rng(0))
    assert gains.shape == (200, 3)
    exposure = np.log(gains).mean(axis=1)
    assert exposure.std() == pytest.approx(0.2, rel=1e-6)
    steps = np.abs(np.diff(exposure))
    assert steps.max() < 0.05 * np.ptp(exposure)  # smooth, not a new draw per frame
    balance = np.log(gains) - exposure[:, None]
    assert 0.01 < balance.std() < 0.2  # white balance drifts too, less than the exposure
    np.testing.assert_array_equal(frame_gains(5, 0.0, np.random.default_rng(0)), np.ones((5, 3)))
    with pytest.raises(ValueError, match="between 0 and 1"):
        frame_gains(5, 1.5, np.random.default_rng(0))


def test_exposed_saturates_and_identity_is_a_no_op() -> None:
    rgb = np.array([[[100, 200, 250]]], np.uint8)
    assert exposed(rgb, np.ones(3)) is rgb
    np.testing.assert_array_equal(exposed(rgb, np.array([1.1, 1.1, 0.5])), [[[110, 220, 125]]])
    np.testing.assert_array_equal(exposed(rgb, np.full(3, 1.2)), [[[120, 240, 255]]])


def test_an_exposure_spread_changes_colour_only_and_is_detected() -> None:
    small = SynthConfig(seed=0, frames=6, width=96, height=72, noise="default")
    constant = generate_scene(small)
    varying = generate_scene(replace(small, exposure_spread=0.25))
    for c, v in zip(constant.capture.frames, varying.capture.frames, strict=True):
        np.testing.assert_array_equal(c.depth, v.depth)
        np.testing.assert_array_equal(c.c2w, v.c2w)
    for c_map, v_map in zip(constant.semantic, varying.semantic, strict=True):
        np.testing.assert_array_equal(c_map.classes, v_map.classes)
    np.testing.assert_array_equal(constant.ground_truth.points, varying.ground_truth.points)
    assert colour_changes(constant.capture.frames)["largest_change"] < 0.01
    assert colour_changes(varying.capture.frames)["largest_change"] > 0.05
    with pytest.raises(ValueError, match="exposure_spread must be between 0 and 1"):
        SynthConfig(exposure_spread=-0.1)


def test_the_cli_writes_the_spread(tmp_path: Path) -> None:
    out = tmp_path / "scene"
    args = ["synth", str(out), "--frames", "2", "--size", "64x48", "--exposure-spread", "0.3"]
    assert main(args) == 0
    assert json.loads((out / "scene.json").read_text())["exposure_spread"] == 0.3
    assert main(["synth", str(tmp_path / "bad"), "--exposure-spread", "2"]) == 2
