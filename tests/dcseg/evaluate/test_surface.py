"""Distance of Gaussian centres to the true surface, against its plane fits."""

from __future__ import annotations

import numpy as np
import pytest

from dcseg.evaluate.surface import surface_distances, surface_report


def floor_samples(spacing: float = 0.015) -> np.ndarray:
    """A 1 m x 1 m floor at z = 0 sampled every ``spacing`` metres."""
    u = np.arange(0.0, 1.0, spacing)
    x, y = np.meshgrid(u, u)
    return np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)


def test_distance_is_to_the_surface_not_to_its_samples() -> None:
    """Centres on the floor between samples are 0 away (the nearest sample is up to ~1 cm
    away); centres 2 cm above it are 2 cm away."""
    rng = np.random.default_rng(0)
    on = np.column_stack([rng.uniform(0.2, 0.8, (100, 2)), np.zeros(100)])
    above = on + [0.0, 0.0, 0.02]
    d = surface_distances(np.vstack([on, above]), floor_samples())
    np.testing.assert_allclose(d[:100], 0.0, atol=1e-9)
    np.testing.assert_allclose(d[100:], 0.02, atol=1e-9)


def test_report_counts_only_opaque_gaussians() -> None:
    centres = np.array([[0.5, 0.5, 0.0], [0.5, 0.5, 0.003], [0.5, 0.5, 0.3]])
    report = surface_report(centres, np.array([0.9, 0.9, 0.1]), floor_samples())
    assert report["opaque"] == 2
    assert report["median"] == pytest.approx(0.0015)
    assert report["within_1cm"] == 1.0


def test_too_few_surface_points_are_refused() -> None:
    with pytest.raises(ValueError, match="surface points"):
        surface_distances(np.zeros((1, 3)), np.zeros((2, 3)))
