"""Per-Gaussian class evidence: sparse sums over blending weights match a brute-force count."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from dcseg.blend import BlendWeights
from dcseg.segment.evidence import agreement_torch, class_agreement, view_agreement
from tests.dcseg.test_blend import random_blend


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
