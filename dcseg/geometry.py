"""Point-cloud geometry shared by the stages (numpy and scipy only)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

BLOCK = 65_536
"""Points per block of :func:`local_axes` (bounds the ``[B, k, 3]`` neighbour table)."""


def local_axes(
    points: NDArray[np.float64], k: int
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Principal axes of each point's ``k`` nearest neighbours (itself included).

    Args:
        points: ``[M, 3]`` with ``M >= k``.
        k: neighbours per point.

    Returns:
        ``(values [M, 3], vectors [M, 3, 3])``: the neighbours' covariance eigenvalues in
        ascending order and the matching unit eigenvectors as columns, so
        ``vectors[:, :, 0]`` is the local surface normal (up to sign).
    """
    tree = cKDTree(points)
    values = np.empty((len(points), 3))
    vectors = np.empty((len(points), 3, 3))
    for start in range(0, len(points), BLOCK):
        _, index = tree.query(points[start : start + BLOCK], k=k)
        local = points[index] - points[index].mean(axis=1, keepdims=True)
        cov = np.einsum("mki,mkj->mij", local, local) / k
        values[start : start + BLOCK], vectors[start : start + BLOCK] = np.linalg.eigh(cov)
    return values, vectors
