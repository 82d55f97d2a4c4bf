"""Pose refinement ``auto``: misaligned poses detected from the depth, exact poses left alone."""

from __future__ import annotations

from dataclasses import replace

import pytest

from dcseg.reconstruct import fit_gaussians
from dcseg.reconstruct.config import ReconstructConfig
from dcseg.reconstruct.job import config_changes
from dcseg.reconstruct.pose_check import THRESHOLD, TILT_THRESHOLD, decide, detection_report
from dcseg.reconstruct.sensor import sensor_report
from dcseg.types import Capture


def test_the_modes_decide() -> None:
    above, below = {"ratio": THRESHOLD * 1.5}, {"ratio": THRESHOLD / 2}
    assert decide("auto", above) and not decide("auto", below)
    assert not decide("auto", None) and not decide("auto", {"ratio": None})
    assert decide("on", below) and decide("on", None)
    assert not decide("off", above)
    tilted = {"ratio": THRESHOLD / 2, "tilt_deg": TILT_THRESHOLD * 1.5}
    assert decide("auto", tilted) and not decide("auto", {**tilted, "tilt_deg": 0.01})
    report = detection_report(above, "off", False)
    expected = {"threshold": THRESHOLD, "tilt_threshold_deg": TILT_THRESHOLD, "detected": True}
    assert report == {**expected, "mode": "off", "refined": False}


def test_the_option_is_validated() -> None:
    with pytest.raises(ValueError, match="pose_refinement must be auto, on or off"):
        ReconstructConfig(pose_refinement="sometimes")
    assert ReconstructConfig().pose_refinement == "auto"


def _scene(deg: float, metres: float) -> Capture:
    pytest.importorskip("pybullet", reason="the synthetic scene generator needs pybullet")
    from dcseg.synth import SynthConfig, generate_scene

    cfg = SynthConfig(
        seed=0, frames=16, width=160, height=120, pose_error_deg=deg, pose_error_m=metres
    )
    return generate_scene(cfg).capture


@pytest.fixture(scope="module")
def exact() -> Capture:
    return _scene(0.0, 0.0)


@pytest.fixture(scope="module")
def misaligned() -> Capture:
    return _scene(0.5, 0.01)


def test_a_known_pose_error_is_detected_and_exact_poses_are_not(
    exact: Capture, misaligned: Capture
) -> None:
    good = sensor_report(exact.frames, drop_flying=True)["poses"]
    bad = sensor_report(misaligned.frames, drop_flying=True)["poses"]
    assert good["ratio"] < THRESHOLD < bad["ratio"], (good, bad)
    assert not decide("auto", good) and decide("auto", bad)


def test_auto_refines_the_misaligned_capture_only(exact: Capture, misaligned: Capture) -> None:
    tiny = ReconstructConfig(
        iterations=12, holdout=4, train_downscale=1, init_pixel_stride=4, sh_degree=0,
        densify_from=100, pose_from=4, pose_align_steps=2, max_gaussians=3000,
    )  # fmt: skip
    kept = fit_gaussians(exact, tiny)
    assert kept.poses is None
    assert kept.sensor["poses"]["refined"] is False and kept.sensor["poses"]["mode"] == "auto"
    changes = {"pose_lr": {"requested": tiny.pose_lr, "applied": 0.0}}
    assert config_changes(tiny, kept.applied) == changes
    refined = fit_gaussians(misaligned, tiny)
    assert refined.poses is not None and refined.sensor["poses"]["refined"] is True
    assert config_changes(tiny, refined.applied) == {}
    assert refined.sensor["poses"]["detected"] is True
    off = fit_gaussians(misaligned, replace(tiny, pose_refinement="off"))
    assert off.poses is None and off.sensor["poses"]["detected"] is True
