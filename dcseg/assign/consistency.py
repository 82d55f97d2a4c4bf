"""Drop Gaussians that their own class-mask evidence contradicts from their labelled cluster.

A cluster's class is decided by votes over whole cluster masks, so a cluster that also holds a
few Gaussians of a neighbouring surface (a ring of floor around a ball, a floor patch whose
features resemble a toy's) labels them with its class: in 3D and in every view. Each such
Gaussian has its own evidence too — its blending weight over the pixels each class-aware map
gives each class (:func:`dcseg.segment.evidence.class_agreement`) — and when that evidence
gives the cluster's class only a small share, the Gaussian leaves the cluster (becomes noise).
Class noise that is per view (a whole object mislabelled in some views) leaves an object's
Gaussians a large share of their class, so they stay.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray


def inconsistent(
    classes: NDArray[np.integer[Any]],
    agree: NDArray[np.floating[Any]],
    total: NDArray[np.floating[Any]],
    min_share: float,
) -> NDArray[np.bool_]:
    """Which Gaussians' evidence gives their cluster's class less than ``min_share``.

    Args:
        classes: ``[N]`` class of every Gaussian's cluster (-1 = none: never inconsistent).
        agree: ``[N]`` evidence for that class.
        total: ``[N]`` evidence for any class; a Gaussian with none is never inconsistent.
        min_share: the smallest share of its evidence the cluster's class must get, in [0, 1].

    Returns:
        ``[N]`` bool.

    Example:
        >>> inconsistent(np.array([0, 0, -1, 1]), np.array([1.0, 0.1, 0.0, 0.0]),
        ...              np.array([2.0, 2.0, 2.0, 0.0]), 0.15).tolist()
        [False, True, False, False]
    """
    if not 0.0 <= min_share <= 1.0:
        raise ValueError(f"min_share must be in [0, 1], got {min_share}")
    classes = np.asarray(classes)
    if not (classes.shape == np.shape(agree) == np.shape(total)):
        raise ValueError(
            f"classes {classes.shape}, agree {np.shape(agree)} and total {np.shape(total)} differ"
        )
    total = np.asarray(total, dtype=np.float64)
    low: NDArray[np.bool_] = (classes >= 0) & (total > 0) & (agree < min_share * total)
    return low
