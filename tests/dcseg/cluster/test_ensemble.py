"""Clustering ensemble: the medoid partition, and ensemble 1 = the single fit."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from dcseg.cluster import ClusterConfig, cluster_features
from dcseg.cluster.ensemble import consensus_partition, fit_partition, medoid
from tests.dcseg.cluster.test_cluster import blobs


def test_medoid_picks_the_partition_the_others_agree_with() -> None:
    truth = np.repeat(np.arange(4), 50)
    split = np.where(truth == 0, np.arange(200) % 2 + 10, truth)  # blob 0 cut in two
    merged = np.where(truth == 1, 0, truth)  # blobs 0 and 1 joined
    rng = np.random.default_rng(0)
    scrambled = rng.permutation(truth)
    relabelled = 7 - truth  # the truth under other names
    partitions = [split, scrambled, truth, merged, relabelled]
    assert medoid(partitions, seed=0) in (2, 4)  # both are the typical partition
    assert medoid([scrambled, split, merged], seed=0) != 0
    assert medoid([split], seed=0) == 0


def test_ensemble_of_one_is_the_single_fit() -> None:
    feats, _, _ = blobs(n=3000)
    cfg = ClusterConfig(seed=4, min_sample_size=500, max_sample_size=500)
    single = fit_partition(feats, cfg, None)
    consensus = consensus_partition(feats, cfg)
    for a, b in zip(single, consensus, strict=True):
        np.testing.assert_array_equal(a, b)


def test_ensemble_returns_one_of_its_fits() -> None:
    feats, _, _ = blobs(n=3000, k=6, noise=0.3, seed=2)
    cfg = ClusterConfig(seed=1, ensemble=3, min_sample_size=400, max_sample_size=400)
    labels, _, centers = consensus_partition(feats, cfg)
    fits = [fit_partition(feats, replace(cfg, seed=s), None)[0] for s in (1, 2, 3)]
    assert any(np.array_equal(labels, f) for f in fits)
    assert centers.shape[1] == feats.shape[1] and labels.max() < centers.shape[0]


def test_cluster_features_with_ensemble_keeps_quality() -> None:
    from sklearn.metrics import adjusted_rand_score

    feats, xyz, truth = blobs()
    result = cluster_features(feats, xyz, None, ClusterConfig(ensemble=3))
    assert result.n_clusters == 5
    assert adjusted_rand_score(truth, result.labels) >= 0.95


def test_ensemble_must_be_positive() -> None:
    with pytest.raises(ValueError, match="ensemble"):
        ClusterConfig(ensemble=0)
