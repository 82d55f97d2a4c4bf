"""The sensor-depth filter: noise-bounded window medians on a sampled grid."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.typing import NDArray

from dcseg.reconstruct.config import ReconstructConfig
from dcseg.reconstruct.depth_filter import DepthFilter, denoise_depth, window_median
from dcseg.reconstruct.init import backproject
from dcseg.reconstruct.views import make_view
from dcseg.types import Frame, Intrinsics


def slanted_wall(h: int = 120, w: int = 160) -> NDArray[np.float32]:
    """Depth of a plane seen at an angle (1.5-2.5 m; a plane is linear in inverse depth) with
    a box 0.5 m in front of it."""
    u = np.linspace(0.0, 1.0, w)
    depth = np.tile(1.0 / (1.0 / 1.5 - (1.0 / 1.5 - 1.0 / 2.5) * u), (h, 1))
    depth[40:80, 60:100] -= 0.5
    return depth.astype(np.float32)


def noisy(depth: NDArray[np.float32], sigma: float, seed: int = 0) -> NDArray[np.float32]:
    rng = np.random.default_rng(seed)
    return (depth + rng.normal(0.0, sigma, depth.shape) * depth * depth).astype(np.float32)


def test_noise_free_depth_is_left_as_it_is() -> None:
    depth = slanted_wall()
    depth[5, 5] = 0.0
    out = denoise_depth(depth, 5, 5.0)
    np.testing.assert_array_equal(out, depth)  # measured noise 0: returned as it is


def test_z_squared_noise_shrinks_and_edges_stay() -> None:
    clean = slanted_wall()
    depth = noisy(clean, 0.004)
    out = denoise_depth(depth, 5, 5.0)
    before = np.abs(depth - clean).mean()
    after = np.abs(out - clean).mean()
    assert after < 0.4 * before
    # the box edge stays a step: pixels either side keep their own surface
    assert abs(out[60, 58] - clean[60, 58]) < 0.1
    assert abs(out[60, 61] - clean[60, 61]) < 0.1


def test_invalid_pixels_stay_invalid_and_do_not_vote() -> None:
    clean = slanted_wall()
    depth = noisy(clean, 0.004)
    depth[10:14, 10:14] = 0.0
    out = denoise_depth(depth, 5, 5.0)
    assert np.all(out[10:14, 10:14] == 0.0)
    assert np.all(out[depth > 0] > 1.0)  # no zero pulled a median down


def test_a_grid_is_the_same_pixels_as_the_whole_image() -> None:
    depth = noisy(slanted_wall(), 0.002)
    whole = denoise_depth(depth, 5, 1e9)  # k huge: every pixel takes its median
    grid = denoise_depth(depth, 5, 1e9, step=2, offset=1)
    np.testing.assert_array_equal(grid, whole[1::2, 1::2])


def test_window_median_matches_numpy_inside() -> None:
    depth = noisy(slanted_wall(), 0.004, seed=3)
    median, full = window_median(depth, 2, 1, 0)
    expected = np.median(depth[8:13, 18:23])
    assert median[10, 20] == pytest.approx(expected)
    assert full[10, 20] and not full[0, 0]


def test_window_one_is_off() -> None:
    depth = noisy(slanted_wall(), 0.004)
    off = DepthFilter(window=1, flying=False)
    np.testing.assert_array_equal(off.grid(depth, 2), depth[::2, ::2])


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"window": 4}, "window"),
        ({"window": 0}, "window"),
        ({"k": 0.0}, "k"),
        ({"step": 0}, "step"),
    ],
)
def test_bad_parameters_are_named(kwargs: dict[str, float], field: str) -> None:
    args = {"window": 5, "k": 5.0, "step": 1} | kwargs
    with pytest.raises(ValueError, match=field):
        denoise_depth(slanted_wall(), int(args["window"]), args["k"], int(args["step"]))


def test_config_rejects_an_even_window() -> None:
    with pytest.raises(ValueError, match="depth_filter_window"):
        ReconstructConfig(depth_filter_window=4)
    with pytest.raises(ValueError, match="depth_filter_k"):
        ReconstructConfig(depth_filter_k=0.0)


def frame_of(depth: NDArray[np.float32]) -> Frame:
    h, w = depth.shape
    k = Intrinsics(fx=60.0, fy=60.0, cx=w / 2, cy=h / 2, width=w, height=h)
    return Frame("f", np.zeros((h, w, 3), np.uint8), depth, k, np.eye(4))


def test_training_views_and_init_points_use_the_filtered_depth() -> None:
    clean = slanted_wall()
    frame = frame_of(noisy(clean, 0.004))
    f = DepthFilter()
    view = make_view(frame, 2, depth_filter=f)
    np.testing.assert_array_equal(view.depth.numpy(), f.grid(frame.depth, 2, 1))
    raw = make_view(frame, 2)
    np.testing.assert_array_equal(raw.depth.numpy(), frame.depth[1::2, 1::2])
    points, _ = backproject(frame, 2, f)
    assert (
        np.abs(points[:, 2] - clean[::2, ::2].ravel()).mean()
        < 0.4 * np.abs(backproject(frame, 2)[0][:, 2] - clean[::2, ::2].ravel()).mean()
    )


def test_the_noise_is_measured_per_metre_squared() -> None:
    clean = slanted_wall()
    frames = [frame_of(noisy(clean, 0.004, seed)) for seed in range(3)]
    assert DepthFilter().noise(frames) == pytest.approx(0.004, rel=0.25)
    assert DepthFilter().noise([frame_of(clean)]) == 0.0
    assert DepthFilter(window=1).noise(frames) is None
