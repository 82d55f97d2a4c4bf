"""neighbour_depth: training frames' depth warped into a held-out frame, a trivial baseline."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.neighbour_depth import at_gap, by_gap, compared, gap_summary, nearest, warped
from dcseg.types import Frame, Intrinsics

K = Intrinsics(fx=40.0, fy=40.0, cx=15.5, cy=11.5, width=32, height=24)


def _frame(name: str, x: float, depth: np.ndarray) -> Frame:
    """A camera at ``(x, 0, 0)`` looking along +z (OpenCV axes) with ``depth``."""
    c2w = np.eye(4)
    c2w[0, 3] = x
    rgb = np.zeros((K.height, K.width, 3), dtype=np.uint8)
    return Frame(name, rgb, depth.astype(np.float32), K, c2w)


def test_a_wall_seen_from_beside_keeps_its_depth_and_leaves_the_unseen_strip_empty() -> None:
    wall = np.full((K.height, K.width), 2.0, dtype=np.float32)
    source = _frame("a", 0.1, wall)  # 0.1 m right: 2 px of parallax at 2 m
    held_out = _frame("t", 0.0, np.zeros_like(wall))
    out = warped(held_out, [source])
    assert np.allclose(out[:, 2:], 2.0)
    assert (out[:, :2] == 0).all()  # left of what the source saw


def test_the_nearest_point_wins_and_the_second_source_fills_the_first_ones_holes() -> None:
    depth = np.full((K.height, K.width), 3.0, dtype=np.float32)
    depth[:, 10:20] = 1.0  # a near box in front of the wall
    first = _frame("a", 0.0, np.where(np.arange(K.width) < 16, depth, 0.0))
    second = _frame("b", 0.0, depth + 0.5)  # a second opinion, further away everywhere
    out = warped(_frame("t", 0.0, np.zeros_like(depth)), [first, second])
    assert np.allclose(out[:, 10:16], 1.0)  # the first source where it has depth
    assert np.allclose(out[:, 16:20], 1.5) and np.allclose(out[:, 20:], 3.5)  # else the second


def test_nearest_takes_the_closest_training_frames_in_capture_order() -> None:
    flat = np.ones((K.height, K.width), dtype=np.float32)
    train = [_frame(n, 0.0, flat) for n in ("f0", "f2", "f3", "f9")]
    order = {"f0": 0, "f1": 1, "f2": 2, "f3": 3, "f9": 9}
    assert [f.name for f in nearest(_frame("f1", 0.0, flat), train, order)] == ["f0", "f2"]


def test_compared_counts_the_render_tail_the_warp_gets_right() -> None:
    truth = np.array([[1.0, 1.0, 2.0, 0.0]], dtype=np.float32)
    render = np.array([[1.5, 1.0, 2.0, 5.0]], dtype=np.float32)  # 0.5 m off at pixel 0
    warp = np.array([[1.01, 1.2, 0.0, 1.0]], dtype=np.float32)  # no warp at pixel 2
    sums = compared(render, truth, warp)
    assert sums["pixels"] == 2 and sums["valid"] == 3
    assert sums["render_abs"] == pytest.approx(0.5)
    assert sums["warp_abs"] == pytest.approx(0.21, abs=1e-6)
    assert sums["render_tail"] == 1 and sums["tail_warp_agrees"] == 1


def test_at_gap_counts_training_frames_before_the_held_out_one_else_after() -> None:
    flat = np.ones((K.height, K.width), dtype=np.float32)
    names = ["f0", "f1", "f3", "f4", "f5"]
    train = [_frame(n, 0.0, flat) for n in reversed(names)]  # any order in
    order = {n: int(n[1]) for n in [*names, "f2"]}
    held_out = _frame("f2", 0.0, flat)
    assert [getattr(at_gap(held_out, train, order, g), "name", None) for g in (1, 2, 3, 4)] == [
        "f1", "f0", "f5", None,
    ]  # fmt: skip


def test_gap_summary_splits_core_and_tail_for_warp_and_render() -> None:
    truth = np.full((1, 4), 2.0, dtype=np.float32)
    warp = np.array([[2.01, 2.02, 0.0, 2.5]], dtype=np.float32)  # pixel 2: nothing warped
    render = np.array([[2.0, 2.04, 9.0, 2.0]], dtype=np.float32)
    summary = gap_summary(*by_gap(render, truth, warp))
    assert summary["pixels"] == 3
    assert summary["warp_mae_mm"] == pytest.approx(1e3 * 0.53 / 3, rel=1e-4)
    assert summary["warp_core_mae_mm"] == pytest.approx(15.0, rel=1e-3)
    assert summary["warp_tail_share"] == pytest.approx(1 / 3)
    assert summary["render_mae_mm"] == pytest.approx(40 / 3, rel=1e-3)
    assert summary["render_median_mm"] == pytest.approx(0.0, abs=1e-3)
    assert summary["render_tail_share"] == 0.0
