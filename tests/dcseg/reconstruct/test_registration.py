"""Colour/depth misregistration: a known shift between depth and colour recovered and undone,
registered frames left alone, a given shift applied as it is."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from numpy.typing import NDArray

from dcseg.reconstruct import fit_gaussians
from dcseg.reconstruct.config import ReconstructConfig
from dcseg.reconstruct.registration import (
    MIN_EDGE_PIXELS,
    MIN_GAIN,
    Registration,
    colour_pose,
    decide,
    depth_edges,
    estimate,
    registered,
    registered_depth,
    shifted,
)
from dcseg.types import Capture, Frame, Intrinsics

K = Intrinsics(fx=100.0, fy=100.0, cx=63.5, cy=47.5, width=128, height=96)


def boxes(seed: int) -> tuple[NDArray[np.uint8], NDArray[np.float32]]:
    """Colour and registered depth of a few boxes (random grey, 1-1.5 m) before a 2 m wall."""
    rng = np.random.default_rng(seed)
    rgb = np.full((96, 128, 3), 60, np.uint8)
    depth = np.full((96, 128), 2.0, np.float32)
    for _ in range(4):
        x, y = rng.integers(10, 90), rng.integers(10, 60)
        w, h = rng.integers(12, 30), rng.integers(12, 30)
        rgb[y : y + h, x : x + w] = rng.integers(120, 250)
        depth[y : y + h, x : x + w] = rng.uniform(1.0, 1.5)
    return rgb, depth


def frames(shift: tuple[int, int]) -> list[Frame]:
    out = []
    for seed in range(3):
        rgb, depth = boxes(seed)
        out.append(Frame(f"f{seed}", rgb, shifted(depth, shift), K, np.eye(4)))
    return out


def test_shifted_moves_an_image_and_leaves_no_depth_where_nothing_moved_in() -> None:
    image = np.arange(12, dtype=np.float32).reshape(3, 4) + 1
    right_up = shifted(image, (1, -1))
    np.testing.assert_array_equal(right_up[:2, 1:], image[1:, :3])
    assert not right_up[:, 0].any() and not right_up[2].any()
    assert shifted(image, (0, 0)) is image
    assert not shifted(image, (5, 0)).any()


def test_a_known_shift_is_recovered_and_registered_frames_measure_none() -> None:
    measured = estimate(frames((3, -2)))  # depth 3 px right and 2 px up of its colour
    assert measured["shift_px"] == [-3, 2], measured
    assert measured["gain"] > 2 * MIN_GAIN
    assert measured["registration"] == {
        "scale": 1.0, "shift_px": [-3, 2], "parallax_px_m": 0.0, "at_size": [128, 96]
    }  # fmt: skip
    assert decide("auto", (0, 0), measured) == Registration(shift_px=(-3.0, 2.0), size=(128, 96))
    fixed = registered(frames((3, -2)), Registration(shift_px=(-3.0, 2.0)))
    inner = (slice(5, -5), slice(5, -5))
    np.testing.assert_array_equal(fixed[0].depth[inner], boxes(0)[1][inner])
    exact = estimate(frames((0, 0)))
    assert exact["shift_px"] == [0, 0] and exact["gain"] == 0.0
    assert decide("auto", (0, 0), exact).identity


def test_the_decision_follows_the_mode_and_a_given_shift() -> None:
    reg = {"scale": 0.9, "shift_px": [2, 0], "parallax_px_m": -12.0}
    measured = {"registration": reg, "gain": 0.5, "edge_pixels": MIN_EDGE_PIXELS}
    assert decide("auto", (0, 0), measured) == Registration(0.9, (2.0, 0.0), -12.0)
    assert decide("auto", (0, 0), {**measured, "edge_pixels": MIN_EDGE_PIXELS - 1}).identity
    assert decide("off", (0, 0), measured).identity
    assert decide("auto", (0, 0), {**measured, "gain": MIN_GAIN / 2}).identity
    given = Registration(shift_px=(-1.0, 4.0))
    assert decide("auto", (-1, 4), measured) == given  # given wins, whatever is measured
    assert decide("off", (-1, 4), None) == given
    assert decide("auto", (0, 0), {"registration": None, "gain": None}).identity


def colour_camera_frames(reg: Registration) -> list[Frame]:
    """The boxes' colour with depth from a depth camera that ``reg`` maps onto it (no
    parallax): each depth pixel takes the colour camera's depth where ``reg`` sends it."""
    v, u = np.mgrid[0:96, 0:128].astype(np.float64)
    uc = np.rint(reg.scale * (u - K.cx) + K.cx + reg.shift_px[0]).astype(int)
    vc = np.rint(reg.scale * (v - K.cy) + K.cy + reg.shift_px[1]).astype(int)
    inside = (uc >= 0) & (uc < 128) & (vc >= 0) & (vc < 96)
    out = []
    for seed in range(3):
        rgb, depth = boxes(seed)
        raw = np.zeros_like(depth)
        raw[inside] = depth[vc[inside], uc[inside]]
        out.append(Frame(f"f{seed}", rgb, raw, K, np.eye(4)))
    return out


def test_a_colour_camera_with_another_focal_length_is_recovered_and_registered() -> None:
    truth = Registration(0.9, (2.0, -1.0))  # Kinect v1: colour focal 0.9 x the depth one's
    measured = estimate(colour_camera_frames(truth))
    found = Registration.of_record(measured["registration"])
    assert abs(found.scale - 0.9) <= 0.01 and abs(found.parallax) <= 4.0, measured
    assert np.allclose(found.shift_px, truth.shift_px, atol=1.5), measured
    assert measured["gain"] > 2 * MIN_GAIN
    fixed = registered_depth(colour_camera_frames(truth)[0], found)
    expected = boxes(0)[1]
    agree = np.abs(fixed - expected) < 0.01
    assert agree[fixed > 0].mean() > 0.97 and (fixed > 0)[8:-8, 8:-8].mean() > 0.97


def test_a_parallax_moves_near_depth_further_and_the_pose_to_the_colour_camera() -> None:
    depth = np.zeros((96, 128), np.float32)
    depth[40, 60], depth[50, 60] = 1.0, 2.0
    frame = Frame("f", np.zeros((96, 128, 3), np.uint8), depth, K, np.eye(4))
    reg = Registration(parallax=-10.0)  # 10 px at 1 m, 5 px at 2 m to the left
    moved = registered_depth(frame, reg)
    assert moved[40, 50] == 1.0 and moved[50, 55] == 2.0 and np.count_nonzero(moved) == 2
    assert colour_pose(frame, reg)[0, 3] == pytest.approx(0.1)  # 10 px m / 100 px = 0.1 m
    assert reg.baseline_m(K.fx) == pytest.approx(0.1)  # the colour camera sits 10 cm right
    # found at twice the size (focal 200 px there): 10 px m is 5 cm, at any size
    twice = Registration(parallax=-10.0, size=(256, 192))
    assert colour_pose(frame, twice)[0, 3] == pytest.approx(0.05)


def test_a_half_pixel_shift_moves_every_pixel_and_a_registration_follows_the_size() -> None:
    depth = np.ones((96, 128), np.float32)
    frame = Frame("f", np.zeros((96, 128, 3), np.uint8), depth, K, np.eye(4))
    moved = registered_depth(frame, Registration(1.0, (0.5, 0.0)))
    assert moved[:, 1:].all() and not moved[:, 0].any()  # none lost to ties, none doubled
    half = Registration(1.0, (4.0, 2.0), size=(256, 192))  # found at twice this frame's size
    np.testing.assert_array_equal(
        registered_depth(boxes_frame(), half), shifted(boxes(0)[1], (2, 1))
    )


def boxes_frame() -> Frame:
    rgb, depth = boxes(0)
    return Frame("f0", rgb, depth, K, np.eye(4))


def test_a_registration_record_is_checked_field_by_field() -> None:
    reg = Registration(0.905, (-6.5, -1.0), -12.0, (640, 480))
    assert Registration.of_record(reg.record()) == reg
    with pytest.raises(ValueError, match='"at_size"'):
        Registration.of_record({**reg.record(), "at_size": [640]})
    with pytest.raises(ValueError, match='"scale"'):
        Registration.of_record({**reg.record(), "scale": True})
    with pytest.raises(ValueError, match='"scale"'):
        Registration.of_record({**reg.record(), "scale": 0})
    with pytest.raises(ValueError, match='"shift_px"'):
        Registration.of_record({**reg.record(), "shift_px": [1.0]})
    with pytest.raises(ValueError, match="finite"):
        Registration.of_record({**reg.record(), "parallax_px_m": float("nan")})


def test_depth_edges_are_the_jumps_not_the_slopes() -> None:
    ramp = np.tile(np.linspace(1.0, 1.2, 50, dtype=np.float32), (10, 1))  # 0.4 % per pixel
    assert not depth_edges(ramp).any()
    ramp[:, 25:] += 0.5
    assert depth_edges(ramp)[:, 24:26].all() and depth_edges(ramp).sum() == 20


def test_the_options_are_validated() -> None:
    with pytest.raises(ValueError, match="depth_registration must be auto or off"):
        ReconstructConfig(depth_registration="on")
    with pytest.raises(ValueError, match="depth_shift_x must be within"):
        ReconstructConfig(depth_shift_x=40)


@pytest.fixture(scope="module")
def misregistered() -> Capture:
    pytest.importorskip("pybullet", reason="the synthetic scene generator needs pybullet")
    from dcseg.synth import SynthConfig, generate_scene

    cfg = SynthConfig(seed=0, frames=12, width=160, height=120, depth_shift_px=(3, 0))
    return generate_scene(cfg).capture


def test_a_reconstruction_detects_and_undoes_the_synthetic_misregistration(
    misregistered: Capture,
) -> None:
    tiny = ReconstructConfig(
        iterations=4, holdout=4, train_downscale=1, init_pixel_stride=4, sh_degree=0,
        densify_from=100, max_gaussians=3000,
    )  # fmt: skip
    entry = fit_gaussians(misregistered, tiny).sensor["registration"]
    assert entry["mode"] == "auto" and entry["measured"]["shift_px"] == [-3, 0]
    assert entry["applied_shift_px"] == [-3, 0] and entry["applied"]["scale"] == 1.0
    off = fit_gaussians(misregistered, replace(tiny, depth_registration="off"))
    assert off.sensor["registration"]["applied_shift_px"] == [0, 0]
    assert off.sensor["registration"]["measured"] is None
    given = fit_gaussians(misregistered, replace(tiny, depth_shift_x=-2))
    assert given.sensor["registration"]["mode"] == "given"
    assert given.sensor["registration"]["applied_shift_px"] == [-2, 0]
