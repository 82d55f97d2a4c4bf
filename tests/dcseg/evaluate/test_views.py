"""The projection protocol over a scene's views: depth read one view at a time."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import cast

import numpy as np
from numpy.typing import NDArray

from dcseg.evaluate import vote_projection
from dcseg.evaluate.views import view_depths, vote_views
from dcseg.io.run_state import ViewState
from dcseg.types import GroundTruth

K = np.array([[10.0, 0, 4.5], [0, 10.0, 4.5], [0, 0, 1]])


@dataclass
class CountedView:
    """A view that counts the reads of its depth (as a view in the cache folder reads)."""

    name: str
    held: NDArray[np.float32]
    K: NDArray[np.float64] = field(default_factory=lambda: K.copy())
    c2w: NDArray[np.float64] = field(default_factory=lambda: np.eye(4))
    reads: list[str] = field(default_factory=list)

    @property
    def depth(self) -> NDArray[np.float32]:
        self.reads.append(self.name)
        return self.held


def views(*depths: float) -> list[CountedView]:
    return [CountedView(f"v{i}", np.full((10, 10), d, np.float32)) for i, d in enumerate(depths)]


def test_view_depths_are_read_one_view_at_a_time() -> None:
    counted = views(2.0, 3.0, 4.0)
    depths = view_depths(cast("list[ViewState]", counted))
    assert len(depths) == 3 and all(v.reads == [] for v in counted)  # nothing read yet
    assert float(depths[1][0, 0]) == 3.0 and [v.reads for v in counted] == [[], ["v1"], []]
    tail = depths[1:]
    assert len(tail) == 2 and counted[2].reads == []
    assert [float(d[0, 0]) for d in tail] == [3.0, 4.0] and counted[2].reads == ["v2"]


def test_vote_views_is_the_projection_vote_with_each_views_depth() -> None:
    """A wall at 2 m in view v0 (labels 0 | 1 left | right) and at 4 m in v1 (all class 2):
    the first point lies on v0's wall, the second on v1's, the third on neither."""
    counted = views(2.0, 4.0)
    labels = np.zeros((10, 10), dtype=np.int64)
    labels[:, 5:] = 1
    images = [labels, np.full((10, 10), 2)]
    points = np.array([[-0.5, 0.0, 2.0], [0.5, 0.0, 4.0], [0.0, 0.0, 3.0]])
    gt = GroundTruth(points, np.zeros(3, dtype=np.int64))
    out = vote_views(gt, cast("list[ViewState]", counted), images, 3, 0.1)
    assert out.tolist() == [0, 2, -1]
    depths = [v.held for v in counted]
    expected = vote_projection(points, images, depths, [K, K], [np.eye(4)] * 2, 3, 0.1)
    assert np.array_equal(out, expected)
    assert [v.reads for v in counted] == [["v0"], ["v1"]]
