"""Per-Gaussian class evidence: sparse sums over blending weights match a brute-force count."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from dcseg.blend import BlendWeights
from dcseg.segment.evidence import (
    agreement_torch,
    class_agreement,
    class_evidence,
    evidence_torch,
    view_agreement,
    view_evidence,
    vote_3d,
)
from tests.scenes.blends import random_blend


def brute_force(
    blend: BlendWeights, class_map: np.ndarray, classes: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    agree, total = np.zeros(len(classes)), np.zeros(len(classes))
    rows = blend.rows().numpy()
    flat = class_map.reshape(-1)
    for k in range(blend.nnz):
        g, c, w = int(blend.ids[k]), flat[rows[k]], float(blend.weights[k])
        if c >= 0:
            total[g] += w
            agree[g] += w if c == classes[g] else 0.0
    return agree, total


def test_agreement_sums_over_views() -> None:
    rng = np.random.default_rng(0)
    blends = [random_blend(5, 6, 12, seed=s) for s in (3, 4)]
    maps = [rng.integers(-1, 3, size=(5, 6)) for _ in blends]
    classes = rng.integers(-1, 3, size=12)
    agree, total = class_agreement(blends, maps, classes)
    expected = [brute_force(b, m, classes) for b, m in zip(blends, maps, strict=True)]
    assert np.allclose(agree, expected[0][0] + expected[1][0])
    assert np.allclose(total, expected[0][1] + expected[1][1])
    assert np.all(agree <= total + 1e-12) and total.sum() > 0 and agree.sum() > 0


def test_one_pixel_example() -> None:
    offsets = torch.tensor([0, 2, 3])
    blend = BlendWeights(1, 2, offsets, torch.tensor([0, 1, 1]), torch.tensor([0.6, 0.3, 0.9]))
    agree, total = class_agreement([blend], [np.array([[4, -1]])], np.array([4, 5]))
    assert np.allclose(agree, [0.6, 0.0]) and np.allclose(total, [0.6, 0.3])


def test_exception_map_size_names_the_view() -> None:
    blends = [random_blend(5, 6, 4), random_blend(5, 6, 4, seed=1)]
    maps = [np.zeros((5, 6), dtype=np.int64), np.zeros((6, 5), dtype=np.int64)]
    with pytest.raises(ValueError, match=r"view 1: class map \(6, 5\) does not match"):
        class_agreement(blends, maps, np.zeros(4, dtype=np.int64))
    with pytest.raises(ValueError, match="2 blending-weight views but 1 class maps"):
        class_agreement(blends, maps[:1], np.zeros(4, dtype=np.int64))


def test_tensor_path_matches_numba_path() -> None:
    """The path used off the CPU (tensor operations) agrees with the CPU kernel."""
    rng = np.random.default_rng(1)
    blend = random_blend(7, 5, 20, seed=5)
    class_map = rng.integers(-1, 4, size=(7, 5))
    classes = torch.from_numpy(rng.integers(-1, 4, size=20))
    agree, total = view_agreement(blend, class_map, classes)
    ref_agree, ref_total = agreement_torch(blend, torch.from_numpy(class_map.reshape(-1)), classes)
    assert torch.allclose(agree, ref_agree) and torch.allclose(total, ref_total)
    assert total.sum() > 0


def brute_evidence(blend: BlendWeights, class_map: np.ndarray, n: int, c: int) -> np.ndarray:
    out = np.zeros((n, c))
    rows = blend.rows().numpy()
    flat = class_map.reshape(-1)
    for k in range(blend.nnz):
        if flat[rows[k]] >= 0:
            out[int(blend.ids[k]), flat[rows[k]]] += float(blend.weights[k])
    return out


def test_class_evidence_sums_weights_per_class_over_views() -> None:
    rng = np.random.default_rng(2)
    blends = [random_blend(5, 6, 12, seed=s) for s in (7, 8)]
    maps = [rng.integers(-1, 4, size=(5, 6)) for _ in blends]
    evidence = class_evidence(blends, maps, 14, 4)
    expected = sum(brute_evidence(b, m, 14, 4) for b, m in zip(blends, maps, strict=True))
    assert evidence.shape == (14, 4) and np.allclose(evidence, expected)
    assert evidence.sum() > 0 and np.all(evidence[12:] == 0)  # padded rows never seen
    classes = rng.integers(-1, 4, size=14)
    agree, total = class_agreement(blends, maps, classes)
    assert np.allclose(evidence.sum(axis=1), total)  # the same evidence, kept per class
    own = np.where(classes >= 0, evidence[np.arange(14), np.maximum(classes, 0)], 0.0)
    assert np.allclose(own, agree)


def test_class_evidence_tensor_path_matches_numba_path() -> None:
    rng = np.random.default_rng(3)
    blend = random_blend(6, 4, 9, seed=9)
    class_map = rng.integers(-1, 3, size=(6, 4))
    n = int(blend.ids.max()) + 1
    ref = evidence_torch(blend, torch.from_numpy(class_map.reshape(-1)), n, 3)
    assert torch.allclose(view_evidence(blend, class_map, 3), ref) and float(ref.sum()) > 0


def test_vote_3d_takes_the_class_of_largest_summed_weight() -> None:
    """A Gaussian labelled 0 in three views with small weights but 1 in one view with a large
    weight takes 1 (the vote is over weight, not over views); one never seen stays -1."""
    offsets = torch.tensor([0, 1, 2])
    views = [
        BlendWeights(1, 2, offsets, torch.tensor([0, 1]), torch.tensor([w, 0.5]))
        for w in (0.2, 0.2, 0.2, 0.9)
    ]
    maps = [np.array([[0, 2]])] * 3 + [np.array([[1, 2]])]
    evidence = class_evidence(views, maps, 3, 3)
    assert np.allclose(evidence[0], [0.6, 0.9, 0.0])
    assert vote_3d(evidence).tolist() == [1, 2, -1]
    assert vote_3d(evidence, min_evidence=1.6).tolist() == [-1, 2, -1]


def test_class_evidence_refuses_bad_maps() -> None:
    blend = random_blend(5, 6, 4)
    with pytest.raises(ValueError, match=r"view 0: class map values must be in \[-1, 3\)"):
        class_evidence([blend], [np.full((5, 6), 3)], 4, 3)
    with pytest.raises(ValueError, match=r"view 0: class map \(6, 5\) does not match"):
        class_evidence([blend], [np.zeros((6, 5), dtype=np.int64)], 4, 3)
    with pytest.raises(ValueError, match="Gaussian ids go up to 3 but n = 2"):
        class_evidence([blend], [np.zeros((5, 6), dtype=np.int64)], 2, 3)
    with pytest.raises(ValueError, match=r"evidence must be \[N, C\]"):
        vote_3d(np.zeros(4))
