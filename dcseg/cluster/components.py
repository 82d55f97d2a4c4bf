"""Connected components of per-cluster radius graphs, on a grid instead of a pair list.

Two Gaussians of the same cluster are linked when their centres are at most ``radius`` apart;
the components of that graph are what 3D outlier removal judges. Listing every linked pair
(``cKDTree.query_pairs``) costs O(pairs), and at the adaptive radius (20x the median spacing)
a surface point has ~1000 neighbours. Here centres go into cubic cells of edge
``radius / sqrt(3)``: all members of one cell are within ``radius`` of each other, so a cell is
connected by itself, and only neighbouring cells (offsets -2..2 per axis) of the same cluster
need a pair test — and only while they are not yet in the same component (union-find), which
on dense surfaces ends after the first pair. Exact: the same components as the pair list.
"""

from __future__ import annotations

import math
from typing import Any

import numba
import numpy as np
from numpy.typing import NDArray

Array = Any  # numpy arrays inside numba kernels


@numba.njit(cache=True, nogil=True)
def _find(parent: Array, i: int) -> int:
    root = i
    while parent[root] != root:
        root = parent[root]
    while parent[i] != root:  # path compression
        parent[i], i = root, parent[i]
    return root


@numba.njit(cache=True, nogil=True)
def _linked(pos: Array, a0: int, a1: int, b0: int, b1: int, r2: float) -> bool:
    """Is any point of rows ``a0:a1`` within ``sqrt(r2)`` of any point of rows ``b0:b1``?"""
    for i in range(a0, a1):
        for j in range(b0, b1):
            dx = pos[i, 0] - pos[j, 0]
            dy = pos[i, 1] - pos[j, 1]
            dz = pos[i, 2] - pos[j, 2]
            if dx * dx + dy * dy + dz * dz <= r2:
                return True
    return False


@numba.njit(cache=True, nogil=True)
def _cell_components(
    pos: Array, keys: Array, starts: Array, coords: Array, dims: Array, r2: float
) -> Array:
    """Union-find over occupied cells -> root cell per cell.

    ``coords [C, 4]`` = (cluster, x, y, z) per cell in the order of ``keys`` (their sorted,
    unique linear keys over ``dims``); the members of cell ``c`` are ``pos[starts[c]:starts[c+1]]``.
    """
    n_cells = len(keys)
    parent = np.arange(n_cells)
    for c in range(n_cells):
        for dx in range(-2, 3):
            for dy in range(-2, 3):
                for dz in range(-2, 3):
                    if dx * 25 + dy * 5 + dz <= 0:
                        continue  # each unordered pair of cells once, never the cell itself
                    x, y, z = coords[c, 1] + dx, coords[c, 2] + dy, coords[c, 3] + dz
                    if x < 0 or y < 0 or z < 0:
                        continue
                    key = ((coords[c, 0] * dims[1] + x) * dims[2] + y) * dims[3] + z
                    o = np.searchsorted(keys, key)
                    if o >= n_cells or keys[o] != key:
                        continue
                    rc, ro = _find(parent, c), _find(parent, o)
                    if rc == ro:
                        continue
                    if _linked(pos, starts[c], starts[c + 1], starts[o], starts[o + 1], r2):
                        parent[max(rc, ro)] = min(rc, ro)
    for c in range(n_cells):
        parent[c] = _find(parent, c)
    return parent


def cluster_components(
    positions: NDArray[np.float64], labels: NDArray[np.int64], radius: float
) -> NDArray[np.int64]:
    """Component id per Gaussian of its cluster's radius graph (edge iff distance <= radius).

    Args:
        positions: ``[N, 3]`` Gaussian centres.
        labels: ``[N]`` cluster ids; ``-1`` rows get component ``-1``.
        radius: link distance (> 0).

    Returns:
        ``[N]`` int64 ids ``0..M-1``, unique across clusters (a component never spans two).
    """
    out = np.full(len(labels), -1, dtype=np.int64)
    rows = np.flatnonzero(labels >= 0)
    if len(rows) == 0:
        return out
    pos = positions[rows]
    cell = np.floor((pos - pos.min(axis=0)) / (radius / math.sqrt(3.0))).astype(np.int64)
    coords = np.concatenate([labels[rows, None], cell], axis=1)
    dims = coords.max(axis=0) + 3
    if float(np.prod(dims.astype(np.float64))) >= 2.0**62:
        raise ValueError(
            f"radius {radius:g} is too small for the scene extent: the cell grid would need "
            f"{dims[1]}x{dims[2]}x{dims[3]} cells per cluster"
        )
    keys = ((coords[:, 0] * dims[1] + coords[:, 1]) * dims[2] + coords[:, 2]) * dims[3]
    keys += coords[:, 3]
    order = np.argsort(keys, kind="stable")
    cell_keys, first, inverse = np.unique(keys[order], return_index=True, return_inverse=True)
    starts = np.append(first, len(order)).astype(np.int64)
    cell_coords = np.ascontiguousarray(coords[order][first])
    roots = _cell_components(
        np.ascontiguousarray(pos[order]), cell_keys, starts, cell_coords, dims, radius * radius
    )
    _, component = np.unique(roots, return_inverse=True)
    out[rows[order]] = component[inverse]
    return out
