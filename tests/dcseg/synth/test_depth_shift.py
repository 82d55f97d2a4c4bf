"""``dcseg synth --depth-shift``: depth moved against colour, everything else as registered."""

from __future__ import annotations

import numpy as np
import pytest

from dcseg.reconstruct.registration import shifted
from dcseg.synth import SynthConfig, generate_scene

pytest.importorskip("pybullet", reason="the synthetic scene generator needs pybullet")


def test_the_depth_moves_and_the_colour_and_truth_stay() -> None:
    base = SynthConfig(seed=0, frames=2, width=64, height=48)
    plain = generate_scene(base)
    moved = generate_scene(SynthConfig(**{**base.__dict__, "depth_shift_px": (2, -1)}))
    for a, b in zip(plain.capture.frames, moved.capture.frames, strict=True):
        np.testing.assert_array_equal(b.depth, shifted(a.depth, (2, -1)))
        np.testing.assert_array_equal(a.rgb, b.rgb)
        assert not b.depth[:, :2].any() and not b.depth[-1].any()
    for truth, kept in zip(plain.gt_depth, moved.gt_depth, strict=True):
        np.testing.assert_array_equal(truth, kept)


def test_the_shift_is_validated() -> None:
    with pytest.raises(ValueError, match="depth_shift_px must be within"):
        SynthConfig(depth_shift_px=(17, 0))
