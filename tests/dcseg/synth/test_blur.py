"""Motion blur of synthetic views: along the camera's flow, of the asked length, colour only."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from dcseg.synth import SynthConfig, generate_scene
from dcseg.synth.blur import blur_flow, motion_blur
from dcseg.synth.cameras import look_at

K = np.array([[100.0, 0.0, 31.5], [0.0, 100.0, 23.5], [0.0, 0.0, 1.0]])


def _stripes(vertical: bool) -> np.ndarray:
    """A 48x64 image of 8-px black/white stripes (vertical stripes vary along x)."""
    v, u = np.mgrid[0:48, 0:64]
    on = ((u if vertical else v) // 8) % 2 == 1
    return np.repeat((on * 255).astype(np.uint8)[..., None], 3, axis=-1)


def _pan(dx: float) -> tuple[np.ndarray, np.ndarray]:
    """Two poses looking along +y at a wall 2 m away, the second moved ``dx`` metres along x
    (sideways: the image's x axis)."""
    a = look_at(np.array([0.0, 0.0, 1.0]), np.array([0.0, 2.0, 1.0]))
    b = look_at(np.array([dx, 0.0, 1.0]), np.array([dx, 2.0, 1.0]))
    return a, b


def test_flow_of_a_sideways_move_is_the_parallax_of_the_depth() -> None:
    a, b = _pan(0.1)
    depth = np.full((48, 64), 2.0, dtype=np.float32)
    flow = blur_flow(depth, K, a, b)
    # A 0.1 m move at 2 m with f = 100 px shifts every pixel by 5 px along x.
    np.testing.assert_allclose(np.abs(flow[..., 0]), 5.0, atol=1e-6)
    np.testing.assert_allclose(flow[..., 1], 0.0, atol=1e-6)
    depth[:, :32] = 1.0  # nearer half moves twice as far
    near = blur_flow(depth, K, a, b)
    np.testing.assert_allclose(np.abs(near[:, :32, 0]), 10.0, atol=1e-6)


def test_blur_smears_across_the_motion_and_not_along_it() -> None:
    a, b = _pan(0.1)
    flow = blur_flow(np.full((48, 64), 2.0, dtype=np.float32), K, a, b)
    across = _stripes(vertical=True)  # edges across the horizontal motion
    along = _stripes(vertical=False)  # edges parallel to it
    blurred = motion_blur(across, flow, 8.0)
    inner = (slice(4, -4), slice(10, -10))
    assert np.abs(blurred[inner].astype(int) - across[inner]).mean() > 40
    np.testing.assert_array_equal(motion_blur(along, flow, 8.0), along)


def test_blur_length_sets_how_far_an_edge_spreads() -> None:
    a, b = _pan(0.1)
    flow = blur_flow(np.full((48, 64), 2.0, dtype=np.float32), K, a, b)
    image = np.zeros((48, 64, 3), dtype=np.uint8)
    image[:, 32:] = 255
    for length in (4.0, 12.0):
        row = motion_blur(image, flow, length)[24, :, 0].astype(int)
        ramp = int(((row > 5) & (row < 250)).sum())
        assert length - 2 <= ramp <= length + 1, (length, row)


def test_no_blur_returns_the_image_and_bad_lengths_are_refused() -> None:
    a, b = _pan(0.1)
    image = _stripes(vertical=True)
    flow = blur_flow(np.full((48, 64), 2.0, dtype=np.float32), K, a, b)
    assert motion_blur(image, flow, 0.0) is image
    assert motion_blur(image, np.zeros_like(flow), 5.0) is image
    with pytest.raises(ValueError, match="blur length must be between 0 and 50"):
        motion_blur(image, flow, 51.0)
    with pytest.raises(ValueError, match="flow shape"):
        motion_blur(image, flow[:, :10], 5.0)
    with pytest.raises(ValueError, match="motion_blur_px must be between 0 and 50"):
        SynthConfig(motion_blur_px=-1.0)


def test_a_blurred_scene_changes_colour_only() -> None:
    small = SynthConfig(seed=0, frames=3, width=80, height=60, noise="default")
    sharp = generate_scene(small)
    blurred = generate_scene(replace(small, motion_blur_px=6.0))
    for s, b in zip(sharp.capture.frames, blurred.capture.frames, strict=True):
        np.testing.assert_array_equal(s.depth, b.depth)
        np.testing.assert_array_equal(s.c2w, b.c2w)
        assert np.abs(s.rgb.astype(int) - b.rgb).mean() > 1.0
        sharpness = np.abs(np.diff(s.rgb.astype(int), axis=1)).mean()
        assert np.abs(np.diff(b.rgb.astype(int), axis=1)).mean() < sharpness
    for s_map, b_map in zip(sharp.semantic, blurred.semantic, strict=True):
        np.testing.assert_array_equal(s_map.classes, b_map.classes)
    np.testing.assert_array_equal(sharp.ground_truth.points, blurred.ground_truth.points)


def test_a_share_of_the_views_is_blurred_the_rest_stay_sharp() -> None:
    from dcseg.synth.generate import blurred_views

    cfg = SynthConfig(frames=40, motion_blur_px=10.0, motion_blur_share=0.25)
    picked = blurred_views(cfg)
    assert len(picked) == 10 and picked <= set(range(40))
    assert blurred_views(cfg) == picked  # seeded
    assert blurred_views(replace(cfg, seed=1)) != picked
    assert blurred_views(replace(cfg, motion_blur_share=1.0)) == frozenset(range(40))
    assert blurred_views(replace(cfg, motion_blur_px=0.0)) == frozenset()
    with pytest.raises(ValueError, match="motion_blur_share must be between 0 and 1"):
        SynthConfig(motion_blur_share=1.5)
