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
    decide,
    depth_edges,
    estimate,
    registered,
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
    assert decide("auto", (0, 0), measured) == (-3, 2)
    fixed = registered(frames((3, -2)), (-3, 2))
    inner = (slice(5, -5), slice(5, -5))
    np.testing.assert_array_equal(fixed[0].depth[inner], boxes(0)[1][inner])
    exact = estimate(frames((0, 0)))
    assert exact["shift_px"] == [0, 0] and exact["gain"] == 0.0
    assert decide("auto", (0, 0), exact) == (0, 0)


def test_the_decision_follows_the_mode_and_a_given_shift() -> None:
    measured = {"shift_px": [2, 0], "gain": 0.5, "edge_pixels": MIN_EDGE_PIXELS}
    assert decide("auto", (0, 0), measured) == (2, 0)
    assert decide("auto", (0, 0), {**measured, "edge_pixels": MIN_EDGE_PIXELS - 1}) == (0, 0)
    assert decide("off", (0, 0), measured) == (0, 0)
    assert decide("auto", (0, 0), {"shift_px": [2, 0], "gain": MIN_GAIN / 2}) == (0, 0)
    assert decide("auto", (-1, 4), measured) == (-1, 4)  # given wins, whatever is measured
    assert decide("off", (-1, 4), None) == (-1, 4)
    assert decide("auto", (0, 0), {"shift_px": None, "gain": None}) == (0, 0)


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
    assert entry["applied_shift_px"] == [-3, 0]
    off = fit_gaussians(misregistered, replace(tiny, depth_registration="off"))
    assert off.sensor["registration"]["applied_shift_px"] == [0, 0]
    assert off.sensor["registration"]["measured"] is None
    given = fit_gaussians(misregistered, replace(tiny, depth_shift_x=-2))
    assert given.sensor["registration"]["mode"] == "given"
    assert given.sensor["registration"]["applied_shift_px"] == [-2, 0]
