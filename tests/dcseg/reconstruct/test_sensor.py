"""The detected-effects report: depth steps and noise, missing and flying depth, brightness
changes between frames, and how well consecutive frames' depth agrees under their poses."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.typing import NDArray

from dcseg.reconstruct.pose_check import TILT_THRESHOLD
from dcseg.reconstruct.sensor import depth_agreement, exposure, quantisation_line, sensor_report
from dcseg.types import Frame, Intrinsics
from tests.dcseg.reconstruct.test_depth_noise import kinect, room, sensor

K = Intrinsics(fx=200.0, fy=200.0, cx=159.5, cy=119.5, width=320, height=240)


def frame(
    depth: NDArray[np.float32], c2w: NDArray[np.float64] | None = None, grey: int = 120
) -> Frame:
    rgb = np.full((*depth.shape, 3), grey, np.uint8)
    return Frame("f", rgb, depth, K, np.eye(4) if c2w is None else c2w)


def moved(x: float = 0.0, z: float = 0.0) -> NDArray[np.float64]:
    c2w = np.eye(4)
    c2w[0, 3], c2w[2, 3] = x, z
    return c2w


def test_the_report_names_the_depth_sensor_effects() -> None:
    frames = [frame(sensor(room(), 0.003, 0.001, seed=s)) for s in range(3)]
    report = sensor_report(frames, drop_flying=True, median_window=5)
    depth = report["depth"]
    assert depth["noise"]["quantisation_step"] == pytest.approx(0.001, rel=0.01)
    assert depth["noise"]["units_per_metre"] == pytest.approx(1000.0, rel=0.01)  # millimetres
    assert depth["noise"]["disparity_step"] == 0.0
    assert quantisation_line(depth["noise"]) == "step 1.000 mm"
    assert depth["noise"]["a_at_1m"] == pytest.approx(0.003, rel=0.3)
    hole = (room() == 0).mean()
    assert depth["missing_fraction"] == pytest.approx(hole, rel=1e-6)
    assert depth["flying_pixels"]["dropped"] is True
    assert depth["flying_pixels"]["share_of_edge_pixels"] == 0.0
    assert depth["median_filter"] == {"window": 5, "applied": True}  # noisy: filtered
    clean = sensor_report([frame(sensor(room(), 0.0, 0.001))], True, median_window=5)
    assert clean["depth"]["median_filter"]["applied"] is False  # noise-free: left as it is
    assert report["frames_measured"] == 3
    assert report["exposure"]["largest_consecutive_change"] == 0.0


def test_a_brightness_change_between_frames_is_reported() -> None:
    depth = sensor(room(), 0.0, 0.001)
    frames = [frame(depth, grey=g) for g in (100, 100, 130, 130)]
    ex = exposure(frames)
    assert ex["largest_consecutive_change"] == pytest.approx(0.3, abs=0.01)
    assert ex["spread"] == pytest.approx(np.std([100, 100, 130, 130]) / 115, rel=0.01)


def plane_depth(distance: float) -> NDArray[np.float32]:
    """A wall facing the camera ``distance`` metres away."""
    return np.full((240, 320), distance, np.float32)


def test_exact_poses_agree_and_a_pose_error_shows() -> None:
    first = frame(plane_depth(2.0))
    second = frame(plane_depth(2.0), moved(x=0.1))  # the same wall from 10 cm to the side
    exact = depth_agreement([first, second], 0.0, 0.001)
    assert exact is not None and exact["depth_disagreement"] < 1e-6
    assert exact["ratio"] < 1.0
    # the second camera really stood 2 cm closer to the wall than its pose says
    wrong = depth_agreement([first, frame(plane_depth(1.98), moved(x=0.1))], 0.0, 0.001)
    assert wrong is not None
    assert wrong["depth_disagreement"] == pytest.approx(0.02, rel=0.01)
    assert wrong["ratio"] > 10


def test_frames_that_see_nothing_in_common_give_no_agreement() -> None:
    behind = moved(z=5.0)
    behind[:3, :3] = np.diag([-1.0, 1.0, -1.0])  # turned round, facing away
    assert depth_agreement([frame(plane_depth(2.0)), frame(plane_depth(2.0), behind)], 0, 0) is None
    assert sensor_report([], drop_flying=True) == {}


def tilted_wall(degrees: float, noise: float, seed: int) -> NDArray[np.float32]:
    """The wall 2 m away seen by a camera tilted ``degrees`` about its x axis, with noise of
    ``noise`` x z^2 metres."""
    yn = (np.arange(240, dtype=np.float64)[:, None] - K.cy) / K.fy + np.zeros((1, 320))
    theta = np.radians(degrees)
    depth = 2.0 / (np.cos(theta) - np.sin(theta) * yn)
    rng = np.random.default_rng(seed)
    noisy: NDArray[np.float32] = (depth + rng.normal(0.0, noise, depth.shape) * depth**2).astype(
        np.float32
    )
    return noisy


def test_a_rotation_hidden_in_heavy_noise_shows_as_tilt() -> None:
    """A 0.4 deg tilt in noise of 7 mm at 1 m: the ratio to the noise stays low (0.6), the tilt
    is measured; exact poses measure none."""
    straight = [frame(tilted_wall(0.0, 0.007, seed)) for seed in (0, 1)]
    exact = depth_agreement(straight, 0.007, 0.0)
    assert exact is not None and exact["tilt_deg"] < 0.05
    tilted = [straight[0], frame(tilted_wall(0.4, 0.007, 1))]  # its pose says it is straight
    wrong = depth_agreement(tilted, 0.007, 0.0)
    assert wrong is not None and wrong["ratio"] < 0.8
    assert wrong["tilt_deg"] == pytest.approx(0.4, rel=0.2)  # first order: 0.34
    assert wrong["tilt_deg"] > TILT_THRESHOLD > exact["tilt_deg"]


def test_a_disparity_sensor_is_reported_and_logged_as_one() -> None:
    frames = [frame(kinect(room(), 0.0029, 0.0015, seed=s)) for s in range(3)]
    noise = sensor_report(frames, drop_flying=True, median_window=5)["depth"]["noise"]
    assert noise["disparity_step"] == pytest.approx(0.0029, rel=0.002)
    assert noise["quantisation_step"] == 0.0 and noise["units_per_metre"] is None
    assert quantisation_line(noise) == "in disparity (steps 2.9 mm at 1 m, 18.1 mm at 2.5 m)"
    assert quantisation_line({"quantisation_step": 0.0, "disparity_step": 0.0}).startswith("none")
