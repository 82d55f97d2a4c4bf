"""Label completion: unlabelled Gaussians on labelled surfaces take a class."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.typing import NDArray

from dcseg.assign.completion import complete_labels, neighbour_shares

SPACING = 0.02
WALL, FLOOR, DUCK = 0, 1, 2


def plane(n: int) -> NDArray[np.float64]:
    """An ``n x n`` grid of centres at ``SPACING`` in the z = 0 plane."""
    g = np.arange(n) * SPACING
    gx, gy = np.meshgrid(g, g, indexing="ij")
    return np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], axis=1)


def complete(
    means: NDArray[np.float64],
    labels: NDArray[np.int64],
    evidence: NDArray[np.float64],
    **kw: float,
) -> NDArray[np.int64]:
    args = {"radius": 3 * SPACING, "neighbours": 8, "rounds": 3, "evidence_weight": 1.0, **kw}
    return complete_labels(
        means, labels, evidence, radius=float(args["radius"]), neighbours=int(args["neighbours"]),
        rounds=int(args["rounds"]), evidence_weight=float(args["evidence_weight"]),
    )  # fmt: skip


def test_noise_gaussians_on_a_labelled_wall_get_the_wall_label() -> None:
    wall = plane(30)
    rng = np.random.default_rng(0)
    labels = np.full(len(wall), WALL, dtype=np.int64)
    noise = rng.choice(len(wall), size=200, replace=False)
    labels[noise] = -1
    hole = (np.abs(wall[:, 0] - 0.3) < 0.05) & (np.abs(wall[:, 1] - 0.3) < 0.05)
    labels[hole] = -1  # a 5x5 hole needs more than one round to fill
    floater = np.array([[0.3, 0.3, 1.0]])
    means = np.concatenate([wall, floater])
    labels = np.append(labels, -1)
    evidence = np.zeros((len(means), 3))
    out = complete(means, labels, evidence)
    assert np.all(out[:-1] == WALL)
    assert out[-1] == -1, "a floater away from every labelled surface stays unlabelled"
    one_round = complete(means, labels, evidence, rounds=1)
    assert np.any(one_round[:-1] == -1), "the hole's centre is beyond one neighbourhood"
    untouched = complete(means, labels, evidence, rounds=0)
    assert np.array_equal(untouched, labels)


def test_own_evidence_breaks_the_tie_on_a_boundary() -> None:
    """A Gaussian between a wall and a floor Gaussian follows its own class evidence."""
    means = np.array([[0, 0, 0], [2 * SPACING, 0, 0], [SPACING, 0, 0]], dtype=np.float64)
    labels = np.array([WALL, FLOOR, -1])
    evidence = np.zeros((3, 3))
    evidence[2, FLOOR] = 0.9
    evidence[2, WALL] = 0.1
    assert complete(means, labels, evidence)[2] == FLOOR
    evidence[2] = [0.9, 0.1, 0.0]
    assert complete(means, labels, evidence)[2] == WALL


def test_labelled_gaussians_keep_their_class() -> None:
    means = plane(5)
    labels = np.full(25, DUCK)
    labels[::2] = WALL
    evidence = np.zeros((25, 3))
    evidence[:, FLOOR] = 1.0
    assert np.array_equal(complete(means, labels, evidence), labels)


def test_neighbour_shares_ignore_missing_and_unlabelled_neighbours() -> None:
    labels = np.array([0, 1, -1])
    idx = np.array([[0, 1, 3], [2, 3, 3]])  # 3 = missing (cKDTree's len(labels))
    shares = neighbour_shares(labels, idx, 2)
    np.testing.assert_allclose(shares, [[0.5, 0.5], [0.0, 0.0]])


def test_bad_shapes_are_named() -> None:
    with pytest.raises(ValueError, match="evidence"):
        complete(plane(2), np.zeros(4, dtype=np.int64), np.zeros((3, 3)))
    with pytest.raises(ValueError, match="radius"):
        complete(plane(2), np.zeros(4, dtype=np.int64), np.zeros((4, 3)), radius=0.0)


def test_wide_discs_reach_across_their_overlapping_footprints() -> None:
    """A wall of few wide discs, centres 5 contact radii apart: an unlabelled disc whose
    footprint overlaps its labelled neighbours' takes their class; without footprints, or
    when the footprints do not overlap, it stays unlabelled."""
    step = 5 * 3 * SPACING
    means = np.array([[0, 0, 0], [step, 0, 0], [2 * step, 0, 0]], dtype=np.float64)
    labels = np.array([WALL, -1, WALL])
    evidence = np.zeros((3, 3))
    wide = np.full(3, 0.6 * step)
    narrow = np.full(3, 0.4 * step)

    def run(footprints: NDArray[np.float64] | None) -> NDArray[np.int64]:
        return complete_labels(
            means, labels, evidence, radius=3 * SPACING, neighbours=8, rounds=1,
            evidence_weight=1.0, footprints=footprints,
        )  # fmt: skip

    assert run(wide).tolist() == [WALL, WALL, WALL]
    assert run(narrow)[1] == -1, "footprints that do not overlap do not reach"
    assert run(None)[1] == -1, "without footprints: the radius only"
    with pytest.raises(ValueError, match="footprints"):
        run(wide[:2])
