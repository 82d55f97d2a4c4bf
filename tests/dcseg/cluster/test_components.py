"""Grid-based radius-graph components equal the pair-list components (cKDTree + scipy)."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.typing import NDArray
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from dcseg.cluster.components import cluster_components


def reference(
    positions: NDArray[np.float64], labels: NDArray[np.int64], radius: float
) -> list[frozenset[int]]:
    """Components as sets of row indices, from every linked pair of each cluster."""
    groups = []
    for k in np.unique(labels[labels >= 0]):
        rows = np.flatnonzero(labels == k)
        pairs = cKDTree(positions[rows]).query_pairs(radius, output_type="ndarray")
        m = len(rows)
        graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), (m, m))
        _, comp = connected_components(graph, directed=False)
        groups += [frozenset(rows[comp == c].tolist()) for c in np.unique(comp)]
    return sorted(groups, key=min)


def as_groups(comp: NDArray[np.int64]) -> list[frozenset[int]]:
    return sorted(
        (frozenset(np.flatnonzero(comp == c).tolist()) for c in np.unique(comp[comp >= 0])),
        key=min,
    )


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("radius", [0.03, 0.08, 0.2])
def test_matches_pair_list_components(seed: int, radius: float) -> None:
    rng = np.random.default_rng(seed)
    n = 1500
    # clumps and sparse points, so components split and join at every radius
    centres = rng.random((12, 3))
    positions = centres[rng.integers(0, 12, n)] + 0.05 * rng.standard_normal((n, 3))
    positions[: n // 5] = rng.random((n // 5, 3))
    labels = rng.integers(-1, 4, n)
    comp = cluster_components(positions, labels, radius)
    assert np.all((comp == -1) == (labels == -1))
    assert as_groups(comp) == reference(positions, labels, radius)
    for c in np.unique(comp[comp >= 0]):  # a component never spans two clusters
        assert len(np.unique(labels[comp == c])) == 1


def test_boundary_distance_links_and_empty_input() -> None:
    positions = np.array([[0.0, 0, 0], [0.1, 0, 0], [0.3, 0, 0], [0.0, 0, 0]])
    labels = np.array([0, 0, 0, 1])
    comp = cluster_components(positions, labels, 0.1)
    assert comp[0] == comp[1] != comp[2] and comp[3] not in comp[:3]
    assert np.all(cluster_components(positions, np.full(4, -1), 0.1) == -1)


def test_radius_too_small_for_the_extent_is_rejected() -> None:
    positions = np.array([[0.0, 0, 0], [1e9, 1e9, 1e9]])
    with pytest.raises(ValueError, match="too small for the scene extent"):
        cluster_components(positions, np.array([0, 0]), 1e-3)
