"""Gaussians contradicted by their own class evidence: the relative share test."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from dcseg.assign.config import AssignConfig
from dcseg.assign.consistency import inconsistent, mask_agreement


def test_far_below_the_cluster_share_is_inconsistent() -> None:
    labels = np.array([0, 0, 0, 0])
    classes = np.array([2, 2, 2, 2])
    agree = np.array([0.9, 0.9, 0.3, 0.2])
    total = np.ones(4)
    # Cluster share = 2.3 / 4 = 0.575; half of it is 0.2875.
    assert inconsistent(labels, classes, agree, total, 0.5).tolist() == [False, False, False, True]


def test_rare_class_cluster_keeps_its_uniformly_weak_gaussians() -> None:
    # A class the maps miss in most views: every Gaussian has a small share, none is an outlier.
    labels = np.array([0, 0, 0, 1, 1])
    classes = np.array([5, 5, 5, 1, 1])
    agree = np.array([0.1, 0.12, 0.09, 0.9, 0.05])
    total = np.ones(5)
    assert inconsistent(labels, classes, agree, total, 0.5).tolist() == [
        False,
        False,
        False,
        False,
        True,
    ]


def test_noise_unlabelled_and_unseen_gaussians_stay() -> None:
    labels = np.array([-1, 0, 1, 1])
    classes = np.array([-1, -1, 3, 3])
    agree = np.array([0.0, 0.0, 0.0, 4.0])
    total = np.array([5.0, 5.0, 0.0, 4.0])
    # Noise, an unlabelled cluster and a Gaussian without evidence are never inconsistent.
    assert not inconsistent(labels, classes, agree, total, 1.0).any()


def test_ratio_zero_keeps_everything() -> None:
    labels = np.array([0, 0])
    assert not inconsistent(labels, labels, np.array([0.0, 1.0]), np.ones(2), 0.0).any()


def test_exception_bad_ratio_and_shapes() -> None:
    labels = np.zeros(2, dtype=np.int64)
    with pytest.raises(ValueError, match="min_ratio must be in"):
        inconsistent(labels, labels, np.zeros(2), np.ones(2), 1.5)
    with pytest.raises(ValueError, match=r"cluster_labels \(2,\), classes \(2,\), agree \(3,\)"):
        inconsistent(labels, labels, np.zeros(3), np.ones(2), 0.1)
    with pytest.raises(ValueError, match="min_share_ratio must be in"):
        AssignConfig(min_share_ratio=-0.1)


def test_mask_agreement_weighs_evidence_of_labelled_gaussians_only() -> None:
    ev = np.array([[3.0, 1.0], [0.0, 2.0], [5.0, 5.0], [0.0, 0.0]])
    assert mask_agreement(np.array([0, 1, -1, 0]), ev) == pytest.approx(5 / 6)
    assert mask_agreement(np.array([1, 0, -1, -1]), ev) == pytest.approx(1 / 6)
    assert np.isnan(mask_agreement(np.array([-1, -1, -1, 0]), ev))
    with pytest.raises(ValueError, match="N rows"):
        mask_agreement(np.array([0, 1]), ev)


@pytest.mark.parametrize(
    "field, value",
    [("trust_agreement", 1.5), ("trust_agreement", -0.1), ("trusted_share_ratio", 2.0),
     ("trusted_evidence_weight", -1.0)],
)  # fmt: skip
def test_trust_settings_are_checked(field: str, value: float) -> None:
    changes: dict[str, Any] = {field: value}
    with pytest.raises(ValueError, match=field):
        AssignConfig(**changes)
