"""Depth noise and quantisation measured from depth maps (sigma(z) = a z^2, steps, plateaus)."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.typing import NDArray

from dcseg.reconstruct.depth_noise import (
    NEGLIGIBLE,
    disparity_step,
    lattice_step,
    noise_model,
    plane_residuals,
    quantisation_step,
    view_noise,
)


def room(h: int = 240, w: int = 320) -> NDArray[np.float64]:
    """A wall seen at an angle (0.8 to about 3 m; linear in inverse depth, as planes are), a box
    in front of it and a hole of missing depth."""
    u = np.linspace(0.0, 1.0, w)[None, :]
    v = np.linspace(0.0, 1.0, h)[:, None]
    depth = 1.0 / (1.0 / 0.8 - 0.6 * u - 0.2 * v)
    depth[50:125, 100:200] = 1.2
    depth[150:210, 25:75] = 0.0
    return depth


def sensor(
    depth: NDArray[np.float64], a: float, step: float, block: int = 1, seed: int = 0
) -> NDArray[np.float32]:
    """``depth`` with noise ``a z^2`` (constant over ``block x block`` plateaus) rounded to
    multiples of ``step`` (0 = not rounded); invalid stays 0."""
    rng = np.random.default_rng(seed)
    h, w = depth.shape
    cells = rng.normal(0.0, 1.0, (h // block + 1, w // block + 1))
    noise = np.kron(cells, np.ones((block, block)))[:h, :w]
    out = depth + noise * a * depth * depth
    if step > 0:
        out = np.round(out / step) * step
    return np.where(depth > 0, out, 0.0).astype(np.float32)


@pytest.mark.parametrize(
    ("step", "expected"), [(0.001, 0.001), (1 / 6553.5, 1 / 6553.5), (0.0, 0.0)]
)
def test_the_quantisation_step_is_read_from_the_values(step: float, expected: float) -> None:
    found = quantisation_step(sensor(room(), 0.002, step))
    assert found == pytest.approx(expected, rel=0.01, abs=1e-9)


def kinect(depth: NDArray[np.float64], c: float, a: float, seed: int = 0) -> NDArray[np.float32]:
    """``depth`` as a disparity sensor writes it: noise ``a z^2``, inverse depth rounded to
    multiples of ``c`` from an offset (the sensor's own), then the depth to millimetres."""
    noisy = sensor(depth, a, 0.0, seed=seed).astype(np.float64)
    valid = noisy > 0
    offset = 0.123 * c
    inverse = np.round((1.0 / np.where(valid, noisy, 1.0) - offset) / c) * c + offset
    out = np.round(1000.0 / inverse) / 1000.0
    return np.where(valid, out, 0.0).astype(np.float32)


@pytest.mark.parametrize("c", [0.0029, 0.0045])
def test_a_disparity_lattice_under_millimetre_rounding_is_found(c: float) -> None:
    depth = kinect(room(), c, 0.0015)
    assert disparity_step(depth) == pytest.approx(c, rel=0.002)
    assert quantisation_step(depth) == 0.0  # millimetres, but not every one of them: no lattice
    model = noise_model([kinect(room(), c, 0.0015, seed=s) for s in range(2)])
    assert model.disparity_step == pytest.approx(c, rel=0.002)
    assert model.as_dict()["disparity_step"] == model.disparity_step


@pytest.mark.parametrize("step", [0.001, 1 / 6553.5, 0.0])
def test_depth_on_a_depth_lattice_or_continuous_has_no_disparity_lattice(step: float) -> None:
    depth = sensor(room(), 0.002, step)
    assert disparity_step(depth) == 0.0
    assert noise_model([depth]).disparity_step == 0.0


def test_a_lattice_step_is_refined_across_a_range_the_image_does_not_show() -> None:
    c = 0.003
    levels = np.concatenate([np.arange(10) * c, (np.arange(10) + 40) * c]) + 0.2
    blurred = levels + np.random.default_rng(0).uniform(-0.04, 0.04, levels.size) * c
    assert lattice_step(np.sort(blurred)) == pytest.approx(c, rel=0.002)


@pytest.mark.parametrize("a", [0.0015, 0.003, 0.006])
def test_z_squared_noise_in_mm_steps_is_measured(a: float) -> None:
    model = noise_model([sensor(room(), a, 0.001, seed=s) for s in range(2)])
    assert model.step == pytest.approx(0.001, rel=0.01)
    assert model.a == pytest.approx(a, rel=0.3)


@pytest.mark.parametrize("block", [4, 8])
def test_noise_in_plateaus_is_measured(block: int) -> None:
    """Kinect-like: neighbouring pixels share their error (block matching)."""
    depths = [sensor(room(), 0.003, 0.001, block, seed) for seed in range(3)]
    assert noise_model(depths).a == pytest.approx(0.003, rel=0.3)


def test_the_measured_sigma_grows_with_z_squared() -> None:
    bins = noise_model([sensor(room(), 0.003, 0.001, seed=s) for s in range(3)]).bins
    (z0, s0, _), (z1, s1, _) = bins[0], bins[-1]
    assert z1 > 1.5 * z0
    assert s1 / s0 == pytest.approx((z1 / z0) ** 2, rel=0.3)


@pytest.mark.parametrize("step", [0.0, 1 / 6553.5, 0.001])
def test_noise_free_depth_measures_zero_whatever_its_steps(step: float) -> None:
    depth = sensor(room(), 0.0, step)
    assert noise_model([depth]).a == 0.0
    assert view_noise(depth) == 0.0


def test_noise_below_the_step_is_not_mistaken_for_none() -> None:
    """Half a millimetre of noise at 1 m in millimetre steps still dithers them."""
    a = noise_model([sensor(room(), 0.0005, 0.001, seed=s) for s in range(2)]).a
    assert a is not None and a > NEGLIGIBLE
    assert a == pytest.approx(0.0005, rel=0.3)


def test_plane_fits_leave_no_residual_on_a_slanted_plane() -> None:
    depth = room().astype(np.float32)
    z, sd = plane_residuals(depth, 7, 8, 2)
    assert len(z) > 100
    assert np.median(sd) < 1e-6  # inverse depth of a plane is exactly a plane


def test_small_depth_maps_fall_back_to_smaller_windows() -> None:
    depths = [sensor(room(24, 32), 0.003, 0.0, seed=s) for s in range(4)]
    assert noise_model(depths).a == pytest.approx(0.003, rel=0.3)


def test_too_little_valid_depth_gives_no_estimate() -> None:
    depth = np.zeros((40, 40), np.float32)
    model = noise_model([depth])
    assert model.a is None and model.bins == ()
    assert view_noise(depth) == 0.0
    assert model.as_dict()["a_at_1m"] is None


def cluttered() -> NDArray[np.float64]:
    """:func:`room` with its left half full of 12-pixel bars 0.3 m in front of the wall: more
    than half of all windows cross an edge."""
    depth = room()
    for x in range(0, 160, 24):
        depth[:, x : x + 12] = np.where(depth[:, x : x + 12] > 0, 0.9, 0.0)
    return depth


def test_windows_across_edges_do_not_make_noise() -> None:
    depth = cluttered()
    _, sd = plane_residuals(sensor(depth, 0.0, 0.001), 7, 8, 2)
    assert np.mean(sd > 1e-4) > 0.5  # most windows cross a bar's edge
    assert noise_model([sensor(depth, 0.0, 0.001)]).a == 0.0
    noisy = [sensor(depth, 0.003, 0.001, seed=s) for s in range(2)]
    assert noise_model(noisy).a == pytest.approx(0.003, rel=0.3)
