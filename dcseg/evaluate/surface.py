"""How far reconstructed Gaussians sit from the true surfaces (issue 14: surfaces where they
belong) and how much of them they cover (issue 38), measured against a synthetic scene's
ground-truth surface points.

Ground-truth points are a sampling of the surfaces (``dcseg synth`` writes ~1.5 cm spacing), so
the distance to the nearest point has a floor of about half that spacing. Each centre is
measured against the plane fitted to its ``k`` nearest ground-truth points instead (their
smallest principal direction): the distance to the surface itself, not to its samples.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

BLOCK = 65536
"""Centres per block of the plane fits (bounds the ``[B, k, 3]`` neighbour table)."""


def surface_distances(
    centres: NDArray[Any], surface: NDArray[Any], k: int = 8
) -> NDArray[np.float64]:
    """``[M]`` distance of each centre to the local plane of its ``k`` nearest surface points.

    Args:
        centres: ``[M, 3]`` points to measure (Gaussian centres).
        surface: ``[P, 3]`` ground-truth surface samples, ``P >= k >= 3``.
        k: neighbours per plane fit.
    """
    pts = np.asarray(surface, dtype=np.float64).reshape(-1, 3)
    query = np.asarray(centres, dtype=np.float64).reshape(-1, 3)
    if k < 3 or len(pts) < k:
        raise ValueError(f"need k >= 3 and at least k surface points, got k={k}, {len(pts)}")
    tree = cKDTree(pts)
    out = np.empty(len(query))
    for start in range(0, len(query), BLOCK):
        block = query[start : start + BLOCK]
        _, idx = tree.query(block, k=k)
        neighbours = pts[idx]  # [B, k, 3]
        mean = neighbours.mean(axis=1)
        centred = neighbours - mean[:, None, :]
        cov = np.einsum("bki,bkj->bij", centred, centred)
        normal = np.linalg.eigh(cov)[1][:, :, 0]  # smallest eigenvalue's vector
        out[start : start + BLOCK] = np.abs(np.einsum("bi,bi->b", block - mean, normal))
    return out


def surface_report(
    centres: NDArray[Any], opacities: NDArray[Any], surface: NDArray[Any], min_opacity: float = 0.5
) -> dict[str, float]:
    """Distances of the opaque Gaussians' centres (opacity above ``min_opacity``) to the
    surface, in metres: median, 90th percentile, mean, and the share within 1 cm."""
    opaque = np.asarray(opacities).reshape(-1) > min_opacity
    d = surface_distances(np.asarray(centres).reshape(-1, 3)[opaque], surface)
    if d.size == 0:
        return {"opaque": 0.0, "median": float("nan"), "p90": float("nan"),
                "mean": float("nan"), "within_1cm": float("nan")}  # fmt: skip
    return {
        "opaque": float(opaque.sum()),
        "median": float(np.median(d)),
        "p90": float(np.percentile(d, 90)),
        "mean": float(d.mean()),
        "within_1cm": float((d < 0.01).mean()),
    }


def coverage(
    centres: NDArray[Any],
    opacities: NDArray[Any],
    surface: NDArray[Any],
    radius: float = 0.05,
    min_opacity: float = 0.5,
) -> dict[str, float]:
    """How much of the surface the opaque Gaussians (opacity above ``min_opacity``) cover: the
    share of surface points with no opaque centre within ``radius`` metres (the coverage gap)
    and the median distance from a surface point to its nearest opaque centre."""
    opaque = np.asarray(centres, dtype=np.float64).reshape(-1, 3)[
        np.asarray(opacities).reshape(-1) > min_opacity
    ]
    pts = np.asarray(surface, dtype=np.float64).reshape(-1, 3)
    if len(opaque) == 0 or len(pts) == 0:
        return {"gap": 1.0 if len(pts) else float("nan"), "median_to_centre": float("inf")}
    distance, _ = cKDTree(opaque).query(pts, k=1)
    return {
        "gap": float((distance > radius).mean()),
        "median_to_centre": float(np.median(distance)),
    }


def geometry_report(
    centres: NDArray[Any],
    opacities: NDArray[Any],
    surface: NDArray[Any],
    radius: float = 0.05,
    min_opacity: float = 0.5,
) -> dict[str, Any]:
    """Centre-to-surface distances (:func:`surface_report`) and :func:`coverage` of one
    reconstruction against ground-truth surface points, with the thresholds used."""
    return {
        "surface_points": int(np.asarray(surface).reshape(-1, 3).shape[0]),
        "min_opacity": min_opacity,
        "coverage_radius": radius,
        "centre_to_surface": surface_report(centres, opacities, surface, min_opacity),
        "coverage": coverage(centres, opacities, surface, radius, min_opacity),
    }
