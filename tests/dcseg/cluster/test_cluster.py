"""Clustering stage: quality floor on synthetic blobs, determinism, 3D outlier removal."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from numpy.typing import NDArray
from sklearn.metrics import adjusted_rand_score

import dcseg.cluster
from dcseg.cluster import (
    ClusterConfig,
    HdbscanClusterer,
    SklearnHdbscanClusterer,
    adaptive_radius,
    assign_to_centers,
    cluster_features,
    compact_labels,
    fit_clusters,
    remove_outliers_3d,
)
from tests.imports import loaded_after


def blobs(
    n: int = 5000, k: int = 5, dim: int = 16, noise: float = 0.05, seed: int = 0
) -> tuple[NDArray[np.float32], NDArray[np.float64], NDArray[np.int64]]:
    """k well-separated blobs on the unit sphere in feature space, each in its own 3D box."""
    rng = np.random.default_rng(seed)
    centres = rng.standard_normal((k, dim))
    centres /= np.linalg.norm(centres, axis=1, keepdims=True)
    truth = rng.integers(0, k, n)
    feats = centres[truth] + noise * rng.standard_normal((n, dim))
    feats /= np.linalg.norm(feats, axis=1, keepdims=True)
    xyz = 5.0 * np.eye(3)[truth % 3] + 2.0 * (truth // 3)[:, None] + rng.random((n, 3))
    return feats.astype(np.float32), xyz, truth


def test_smoke_blobs_reach_ari_floor() -> None:
    feats, xyz, truth = blobs()
    result = cluster_features(feats, xyz, None, ClusterConfig())
    assert result.n_clusters == 5
    assert result.labels.shape == (5000,) and result.labels.dtype == np.int64
    assert result.centers.shape == (5, 16)
    np.testing.assert_allclose(np.linalg.norm(result.centers, axis=1), 1.0, atol=1e-5)
    assert adjusted_rand_score(truth, result.labels) >= 0.95
    assigned = result.labels >= 0
    cos = np.sum(feats[assigned] * result.centers[result.labels[assigned]], axis=1)
    np.testing.assert_allclose(result.scores[assigned], cos, atol=1e-5)


def test_torch_tensor_input_and_weights() -> None:
    torch = pytest.importorskip("torch")
    feats, xyz, truth = blobs(n=2500)
    result = cluster_features(
        torch.from_numpy(feats), torch.from_numpy(xyz), torch.ones(len(feats)), ClusterConfig()
    )
    assert adjusted_rand_score(truth, result.labels) >= 0.95


def test_deterministic_for_a_seed() -> None:
    feats, xyz, _ = blobs(n=3000, noise=0.2)
    cfg = ClusterConfig(seed=3, min_sample_size=500)
    a = cluster_features(feats, xyz, None, cfg)
    b = cluster_features(feats, xyz, None, cfg)
    np.testing.assert_array_equal(a.labels, b.labels)
    np.testing.assert_array_equal(a.centers, b.centers)
    np.testing.assert_array_equal(a.scores, b.scores)


def test_results_are_read_only() -> None:
    feats, xyz, _ = blobs(n=2000)
    result = cluster_features(feats, xyz, None, ClusterConfig())
    with pytest.raises(ValueError):
        result.labels[0] = 3


def test_far_fragment_of_a_cluster_becomes_noise() -> None:
    feats, xyz, truth = blobs()
    xyz = xyz.copy()
    fragment = np.flatnonzero(truth == 0)[:30]
    xyz[fragment] += 100.0  # same features, far away in 3D
    kept = cluster_features(feats, xyz, None, ClusterConfig(remove_outliers=False))
    # The 30-Gaussian fragment weighs < 5 % of its cluster's main body.
    cleaned = cluster_features(feats, xyz, None, ClusterConfig(min_component_fraction=0.05))
    assert np.all(kept.labels[fragment] >= 0)
    assert np.all(cleaned.labels[fragment] == -1)
    rest = np.setdiff1d(np.arange(len(truth)), fragment)
    # elsewhere only the odd isolated Gaussian at a blob's corner may also be dropped
    same = cleaned.labels[rest] == kept.labels[rest]
    assert same.mean() > 0.999
    assert np.all(cleaned.labels[rest][~same] == -1)


def line(n: int, start: float, spacing: float = 0.1) -> NDArray[np.float64]:
    return np.stack([start + spacing * np.arange(n), np.zeros(n), np.zeros(n)], axis=1)


def test_second_pass_finds_objects_the_sample_missed() -> None:
    """Two 12-Gaussian objects among 20 000: the 1000-point sample holds about one Gaussian of
    each, so only the refit on unassigned Gaussians gives them clusters of their own."""
    feats, xyz, truth = blobs(n=20_000, k=4, seed=1)
    rng = np.random.default_rng(2)
    blob_centres = np.stack([feats[truth == i].mean(0) for i in range(4)])
    # two directions orthogonal to every blob (cosine ~0: no first-pass centre claims them)
    basis = np.linalg.qr(np.concatenate([blob_centres, rng.standard_normal((2, 16))]).T)[0]
    directions = basis[:, 4:6].T
    small = np.repeat(directions, 12, axis=0) + 0.02 * rng.standard_normal((24, 16))
    small /= np.linalg.norm(small, axis=1, keepdims=True)
    feats = np.concatenate([feats, small.astype(np.float32)])
    xyz = np.concatenate([xyz, 20.0 + np.repeat(np.eye(3)[:2], 12, 0) + 0.1 * rng.random((24, 3))])
    cfg = ClusterConfig(min_sample_size=1000, max_sample_size=1000, refit_unassigned=False)
    first = cluster_features(feats, xyz, None, cfg)
    assert first.n_clusters == 4 and np.all(first.labels[-24:] == -1)
    second = cluster_features(feats, xyz, None, replace(cfg, refit_unassigned=True))
    assert second.n_clusters == 6
    np.testing.assert_array_equal(second.labels[:-24], first.labels[:-24])
    assert set(second.labels[-24:-12].tolist()) | set(second.labels[-12:].tolist()) == {4, 5}
    assert len(set(second.labels[-24:-12].tolist())) == 1 == len(set(second.labels[-12:]))
    assert np.all(second.scores[-24:] > 0.9)


def test_remove_outliers_by_size_and_weight_share() -> None:
    # cluster 0: main body of 50 + far piece of 5 (too small); cluster 1: 40 + 20 far away
    pos = np.concatenate([line(50, 0.0), line(5, 100.0), line(40, 200.0), line(20, 300.0)])
    labels = np.repeat([0, 0, 1, 1], [50, 5, 40, 20])
    weights = np.ones(len(pos))
    out = remove_outliers_3d(
        pos, labels, weights, radius=0.15, min_component_size=10, min_component_fraction=0.05
    )
    np.testing.assert_array_equal(out, np.repeat([0, -1, 1, 1], [50, 5, 40, 20]))
    weights[95:] = 0.01  # the 20-piece now weighs < 5 % of cluster 1's main body
    out = remove_outliers_3d(
        pos, labels, weights, radius=0.15, min_component_size=10, min_component_fraction=0.05
    )
    np.testing.assert_array_equal(out, np.repeat([0, -1, 1, -1], [50, 5, 40, 20]))


def test_remove_outliers_leaves_noise_and_rejects_bad_radius() -> None:
    pos = line(12, 0.0)
    labels = np.array([-1] * 2 + [0] * 10)
    out = remove_outliers_3d(
        pos, labels, np.ones(12), radius=0.15, min_component_size=10, min_component_fraction=0.0
    )
    np.testing.assert_array_equal(out, labels)
    with pytest.raises(ValueError, match="radius"):
        remove_outliers_3d(
            pos, labels, np.ones(12), radius=0.0, min_component_size=1, min_component_fraction=0
        )


def test_compact_labels_reindexes_contiguously() -> None:
    centers = np.eye(4, dtype=np.float32)
    labels, kept = compact_labels(np.array([3, -1, 1, 3, 1]), centers)
    np.testing.assert_array_equal(labels, [1, -1, 0, 1, 0])
    np.testing.assert_array_equal(kept, centers[[1, 3]])


def test_emptied_cluster_is_removed_and_reindexed() -> None:
    feats, xyz, truth = blobs(n=2000, k=3)
    xyz = xyz.copy()
    # scatter blob 1 over a huge volume: every Gaussian is its own component -> dropped
    rng = np.random.default_rng(1)
    xyz[truth == 1] = rng.random(((truth == 1).sum(), 3)) * 1e4
    result = cluster_features(feats, xyz, None, ClusterConfig())
    assert result.n_clusters == 2
    assert set(np.unique(result.labels)) == {-1, 0, 1}
    assert np.all(result.labels[truth == 1] == -1)


def test_adaptive_radius() -> None:
    assert adaptive_radius(line(10, 0.0), factor=3.0) == pytest.approx(0.3)
    assert adaptive_radius(np.zeros((4, 3)), factor=3.0) == 0.0


def test_assign_to_centers_similarity_floor_and_ties() -> None:
    x = np.array([[1, 0], [0, 1], [-1, 0], [np.sqrt(0.5), np.sqrt(0.5)]], dtype=np.float32)
    centers = np.array([[1, 0], [0, 1]], dtype=np.float32)
    labels, scores = assign_to_centers(x, centers, min_similarity=0.5)
    np.testing.assert_array_equal(labels, [0, 1, -1, 0])  # tie -> lowest index
    np.testing.assert_allclose(scores, [1, 1, 0, np.sqrt(0.5)], atol=1e-6)
    labels, scores = assign_to_centers(x, np.zeros((0, 2), np.float32), 0.5)
    assert np.all(labels == -1) and np.all(scores == 0)


def test_fit_clusters_on_tiny_input_finds_nothing() -> None:
    centers = fit_clusters(np.full((5, 4), 0.5, np.float32), ClusterConfig())
    assert centers.shape == (0, 4)
    result = cluster_features(np.ones((5, 4)), np.zeros((5, 3)), None, ClusterConfig())
    assert result.n_clusters == 0 and np.all(result.labels == -1)


def test_sample_size_floor_and_cap() -> None:
    from dcseg.cluster.features import sample_indices

    assert len(sample_indices(50_000, ClusterConfig())) == 10_000  # floor
    assert len(sample_indices(5000, ClusterConfig())) == 5000  # floor capped by N
    assert len(sample_indices(10**7, ClusterConfig())) == 20000  # cap
    assert len(sample_indices(10**6, ClusterConfig())) == 20000  # 2 % = 20000
    idx = sample_indices(10**5, ClusterConfig(sample_fraction=0.5, max_sample_size=60000))
    assert len(idx) == 50000 and np.all(np.diff(idx) > 0)


def test_min_samples_means_the_same_in_both_backends() -> None:
    """contrib min_samples=m and sklearn min_samples=m+1 are the same model; ours matches."""
    feats, _, _ = blobs(n=1500, noise=0.15)
    x = feats.astype(np.float64)
    for m in (3, 10):
        a = HdbscanClusterer(10, m, 0.01).fit_predict(x)
        b = SklearnHdbscanClusterer(10, m, 0.01).fit_predict(x)
        assert adjusted_rand_score(a, b) >= 0.99
    cfg = ClusterConfig(clusterer="sklearn")
    assert cfg.resolved_min_samples == cfg.min_cluster_size


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"clusterer": "cuml"}, "clusterer"),
        ({"sample_fraction": 0.0}, "sample_fraction"),
        ({"min_sample_size": 10, "max_sample_size": 5}, "min_sample_size"),
        ({"min_cluster_size": 1}, "min_cluster_size"),
        ({"min_samples": 0}, "min_samples"),
        ({"cluster_selection_epsilon": -1.0}, "cluster_selection_epsilon"),
        ({"min_similarity": 2.0}, "min_similarity"),
        ({"outlier_radius": 0.0}, "outlier_radius"),
        ({"radius_factor": 0.0}, "radius_factor"),
        ({"min_component_size": 0}, "min_component_size"),
        ({"min_component_fraction": 1.5}, "min_component_fraction"),
    ],
)
def test_exception_config(kwargs, match) -> None:
    with pytest.raises(ValueError, match=match):
        ClusterConfig(**kwargs)


def test_exception_inputs() -> None:
    cfg = ClusterConfig()
    with pytest.raises(ValueError, match="features"):
        cluster_features(np.ones(4), np.zeros((4, 3)), None, cfg)
    with pytest.raises(ValueError, match="centers3d"):
        cluster_features(np.ones((4, 2)), np.zeros((3, 3)), None, cfg)
    with pytest.raises(ValueError, match="weights"):
        cluster_features(np.ones((4, 2)), np.zeros((4, 3)), -np.ones(4), cfg)


def test_all_is_sorted_and_complete() -> None:
    assert dcseg.cluster.__all__ == sorted(dcseg.cluster.__all__)
    for name in dcseg.cluster.__all__:
        assert hasattr(dcseg.cluster, name)


def test_config_and_package_import_without_torch_or_hdbscan() -> None:
    statement = "import dcseg.cluster, dcseg.cluster.config"
    assert loaded_after(statement, ("torch", "hdbscan", "sklearn")) == []


def test_docstring_examples() -> None:
    import doctest

    import dcseg.cluster.stage as module

    assert doctest.testmod(module, raise_on_error=True).attempted > 0
