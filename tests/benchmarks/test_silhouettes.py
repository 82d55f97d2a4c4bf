"""silhouettes: how far a render's foreground spills past the sensor's depth edges."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.silhouettes import counts, summary


def _box(grow: int) -> np.ndarray:
    """A 2 m wall with a 1 m box in its middle, the box grown by ``grow`` px on every side."""
    depth = np.full((40, 60), 2.0, dtype=np.float32)
    depth[10 - grow : 30 + grow, 20 - grow : 40 + grow] = 1.0
    return depth


def test_a_render_grown_two_pixels_spills_over_the_first_two_rings_only() -> None:
    truth = _box(0)
    found = summary(counts(_box(2), truth, truth))
    assert found["1 px"]["pixels"] == 22 * 22 - 20 * 20  # the wall's ring round the box
    assert found["1 px"]["render_spilled"] == found["2 px"]["render_spilled"] == 1.0
    assert found["3 px"]["render_spilled"] == found["4 px"]["render_spilled"] == 0.0
    assert all(row["warp_spilled"] == 0.0 for row in found.values())  # the sensor's own edges


def test_pixels_without_depth_or_warp_are_not_counted() -> None:
    truth = _box(0)
    truth[:, :20] = 0.0  # no sensor depth left of the box: its ring's left column is out
    table = counts(_box(1), truth, None)
    assert table[0, 0] == 22 * 22 - 20 * 20 - 22 and table[0, 1] == table[0, 0]
    assert (table[:, 2:] == 0).all()
    assert summary(table)["2 px"]["warp_spilled"] is None
    assert summary(table)["1 px"]["render_spilled"] == pytest.approx(1.0)
