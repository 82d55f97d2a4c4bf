"""Gaussians contradicted by their own class evidence: the share test."""

from __future__ import annotations

import numpy as np
import pytest

from dcseg.assign.config import AssignConfig
from dcseg.assign.consistency import inconsistent


def test_low_share_of_the_cluster_class_is_inconsistent() -> None:
    classes = np.array([2, 2, 2, 2])
    agree = np.array([0.5, 0.14, 0.15, 0.0])
    total = np.ones(4)
    assert inconsistent(classes, agree, total, 0.15).tolist() == [False, True, False, True]


def test_unlabelled_and_unseen_gaussians_stay() -> None:
    classes = np.array([-1, 0, 1])
    agree = np.zeros(3)
    total = np.array([5.0, 0.0, 2.0])
    # -1: no class to contradict; zero total: no evidence; only the last is contradicted.
    assert inconsistent(classes, agree, total, 0.15).tolist() == [False, False, True]


def test_share_zero_keeps_everything() -> None:
    assert not inconsistent(np.array([0, 1]), np.zeros(2), np.ones(2), 0.0).any()


def test_exception_bad_share_and_shapes() -> None:
    with pytest.raises(ValueError, match="min_share must be in"):
        inconsistent(np.zeros(2, dtype=np.int64), np.zeros(2), np.ones(2), 1.5)
    with pytest.raises(ValueError, match=r"classes \(3,\), agree \(2,\)"):
        inconsistent(np.zeros(3, dtype=np.int64), np.zeros(2), np.ones(2), 0.1)
    with pytest.raises(ValueError, match="min_class_share must be in"):
        AssignConfig(min_class_share=-0.1)
