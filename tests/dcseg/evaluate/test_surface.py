"""Distance of Gaussian centres to the true surface, against its plane fits."""

from __future__ import annotations

import numpy as np
import pytest

from dcseg.evaluate.surface import coverage, geometry_report, surface_distances, surface_report


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


def test_coverage_gap_is_the_share_of_surface_without_an_opaque_centre_nearby() -> None:
    """Opaque centres every 2 cm over the left 0.6 m of the floor: its right 0.4 m (less the
    5 cm the last centres reach) is uncovered; a transparent centre on the right counts not."""
    u = np.arange(0.0, 0.6, 0.02)
    x, y = np.meshgrid(u, np.arange(0.0, 1.0, 0.02))
    opaque = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
    centres = np.vstack([opaque, [[0.9, 0.5, 0.0]]])
    opacities = np.r_[np.full(len(opaque), 0.9), 0.1]
    surface = floor_samples()
    result = coverage(centres, opacities, surface)
    right = surface[:, 0] > 0.58 + 0.05
    assert result["gap"] == pytest.approx(right.mean(), abs=0.02)
    assert result["median_to_centre"] < 0.02
    assert coverage(centres, np.full(len(centres), 0.9), surface)["gap"] < result["gap"]
    assert coverage(centres, np.zeros(len(centres)), surface)["gap"] == 1.0


def test_geometry_report_carries_both_measures_and_their_thresholds() -> None:
    centres = np.array([[0.5, 0.5, 0.004], [0.2, 0.2, 0.0]])
    report = geometry_report(centres, np.array([0.9, 0.9]), floor_samples())
    assert report["centre_to_surface"]["median"] == pytest.approx(0.002)
    assert report["coverage"]["gap"] > 0.9  # two centres cover little of a square metre
    assert report["coverage_radius"] == 0.05 and report["min_opacity"] == 0.5
    assert report["surface_points"] == len(floor_samples())
