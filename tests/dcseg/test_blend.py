"""BlendWeights: sparse products agree with a dense reference."""

from __future__ import annotations

import pytest
import torch

import dcseg.blend
from dcseg.blend import BlendWeights
from tests.scenes.blends import random_blend


def dense(blend: BlendWeights, n: int) -> torch.Tensor:
    """[H*W, N] matrix of weights, the brute-force reference."""
    matrix = torch.zeros(blend.height * blend.width, n, dtype=torch.float64)
    rows = blend.rows()
    for k in range(blend.nnz):
        matrix[rows[k], blend.ids[k]] += float(blend.weights[k])
    return matrix


def test_render_matches_dense_product() -> None:
    blend = random_blend(5, 7, 9)
    values = torch.randn(9, 4, dtype=torch.float64)
    expected = (dense(blend, 9) @ values).reshape(5, 7, 4)
    assert torch.allclose(blend.render(values), expected)


def test_gather_matches_render_and_is_differentiable() -> None:
    blend = random_blend(6, 4, 11, seed=1)
    values = torch.randn(11, 3, dtype=torch.float64, requires_grad=True)
    pixels = torch.tensor([0, 23, 5, 5, 12])
    picked = blend.gather(values, pixels)
    assert torch.allclose(picked, blend.render(values).reshape(-1, 3)[pixels])
    torch.autograd.gradcheck(lambda v: blend.gather(v, pixels), (values,))


def test_accumulate_groups_is_one_hot_render() -> None:
    blend = random_blend(4, 4, 10, seed=2)
    group = torch.tensor([0, 1, 2, -1, 0, 1, 2, -1, 0, 1])
    one_hot = torch.zeros(10, 3, dtype=torch.float32)
    keep = group >= 0
    one_hot[keep, group[keep]] = 1.0
    assert torch.allclose(blend.accumulate_groups(group, 3), blend.render(one_hot))


def test_exception_bad_offsets() -> None:
    with pytest.raises(ValueError, match="offsets must have shape"):
        BlendWeights(2, 2, torch.zeros(3, dtype=torch.long), torch.zeros(0), torch.zeros(0))


def test_nbytes_counts_storage() -> None:
    blend = random_blend(3, 3, 4)
    assert blend.nbytes() == 8 * 10 + 8 * blend.nnz + 4 * blend.nnz


DOMINANT = ("dominant_group", "dominant_group_blocks")
"""The numba (CPU) implementation and the PyTorch one used on other devices."""


@pytest.mark.parametrize("method", DOMINANT)
def test_dominant_group_matches_dense_argmax(method: str) -> None:
    blend = random_blend(9, 7, 30, seed=5)
    group = torch.randint(-1, 4, (30,), generator=torch.Generator().manual_seed(0))
    dense = blend.accumulate_groups(group, 4)
    best, arg = dense.max(dim=-1)
    expected = torch.where(best >= 0.2, arg, torch.full_like(arg, -1))
    assert torch.equal(getattr(blend, method)(group, 0.2), expected)
    assert (expected >= 0).sum() > 10 and (expected == -1).sum() > 0


def test_dominant_group_is_the_same_in_pixel_blocks(monkeypatch: pytest.MonkeyPatch) -> None:
    blend = random_blend(9, 7, 30, seed=6)
    group = torch.randint(-1, 5, (30,), generator=torch.Generator().manual_seed(1))
    whole = blend.dominant_group(group, 0.1)
    monkeypatch.setattr(dcseg.blend, "DENSE_BUDGET", 5 * 4)  # 4 pixels per block, 16 blocks
    assert torch.equal(blend.dominant_group_blocks(group, 0.1), whole)
    assert (whole >= 0).sum() > 10 and (whole == -1).sum() > 0


@pytest.mark.parametrize("method", DOMINANT)
def test_dominant_group_ties_and_none(method: str) -> None:
    offsets = torch.tensor([0, 2, 3, 3])
    blend = BlendWeights(1, 3, offsets, torch.tensor([0, 1, 2]), torch.tensor([0.5, 0.5, 0.9]))
    dominant = getattr(blend, method)
    assert dominant(torch.tensor([1, 0, -1]), 0.1).tolist() == [[0, -1, -1]]
    assert dominant(torch.tensor([-1, -1, -1]), 0.1).tolist() == [[-1, -1, -1]]


@pytest.mark.parametrize("method", DOMINANT)
def test_dominant_group_sums_and_floor_in_float32(method: str) -> None:
    """float32 sums: 0.1 + 0.2 == 0.3 ties (lower group wins); a floor equal to a weight claims."""
    offsets = torch.tensor([0, 3, 4])
    ids = torch.tensor([0, 1, 2, 3], dtype=torch.int32)
    weights = torch.tensor([0.1, 0.2, 0.3, 0.7], dtype=torch.float32)
    blend = BlendWeights(1, 2, offsets, ids, weights)
    group = torch.tensor([0, 0, 1, 2])
    assert getattr(blend, method)(group, 0.7).tolist() == [[-1, 2]]
    assert getattr(blend, method)(group, 0.3).tolist() == [[0, 2]]
