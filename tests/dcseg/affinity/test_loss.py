import math

import torch
from torch.autograd import gradcheck

from dcseg.affinity.loss import contrastive_loss, mine_pairs


def _inputs(
    s: int = 6, d: int = 4, t: int = 3, seed: int = 0
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    features = torch.randn(s, d, generator=g, dtype=torch.float64)
    gates = torch.sigmoid(torch.randn(t, d, generator=g, dtype=torch.float64))
    group = torch.randint(0, 3, (t, s), generator=g)
    affinity = group[:, :, None] == group[:, None, :]
    weights = 1.0 + 9.0 * torch.rand(s, s, generator=g, dtype=torch.float64)
    weights = (weights + weights.T) / 2
    draw = torch.rand(s, s, generator=g, dtype=torch.float64)
    return features, gates, affinity, weights, draw


def _reference(
    features: torch.Tensor,
    gates: torch.Tensor,
    affinity: torch.Tensor,
    weights: torch.Tensor,
    draw: torch.Tensor,
    norm_weight: float = 1.0,
) -> torch.Tensor:
    """SAGA's formula written out with boolean indexing, as a test oracle."""
    phi = torch.nn.functional.normalize(features[None] * gates[:, None], dim=-1)
    cos = torch.einsum("tsd,tqd->tsq", phi, phi)
    pos, neg = mine_pairs(cos.detach(), affinity, draw)
    g = affinity.to(cos.dtype)
    w = weights[None].expand_as(cos)
    loss = features.new_zeros(())
    if pos.any():
        loss = loss - (w[:, pos] * g[:, pos] * cos[:, pos]).mean()
    if neg.any():
        loss = loss + (w[:, neg] * (1 - g[:, neg]) * cos[:, neg].clamp(min=0)).mean()
    out: torch.Tensor = loss + norm_weight * (1 - features.norm(dim=-1).mean()) ** 2
    return out


def test_gradcheck_float64():
    features, gates, affinity, weights, draw = _inputs()
    features.requires_grad_(True)
    gates.requires_grad_(True)

    def fn(f, g):
        return contrastive_loss(f, g, affinity, weights, draw, block_rows=4)

    assert gradcheck(fn, (features, gates), eps=1e-6, atol=1e-6)


def test_matches_reference_formula():
    for seed in range(5):
        inputs = _inputs(s=13, d=5, t=4, seed=seed)
        want = _reference(*inputs, norm_weight=0.5)
        for block_rows in (5, 128):
            got = contrastive_loss(*inputs, norm_weight=0.5, block_rows=block_rows)
            torch.testing.assert_close(got, want)


def test_mine_pairs_upper_triangle_and_inconsistent_in_both():
    _, _, affinity, _, draw = _inputs(s=10, t=3, seed=1)
    cos = torch.zeros(3, 10, 10, dtype=torch.float64)  # no hard pairs
    pos, neg = mine_pairs(cos, affinity, draw)
    upper = torch.ones(10, 10, dtype=torch.bool).triu(1)
    assert not (pos & ~upper).any() and not (neg & ~upper).any()
    z = affinity.sum(0)
    inconsistent = (z > 0) & (z < 3) & upper
    assert inconsistent.any()
    assert (pos[inconsistent]).all() and (neg[inconsistent]).all()
    assert not (pos & (z == 0)).any()  # consistent negatives never positive
    assert not (neg & (z == 3)).any()


def test_mine_pairs_hard_pairs():
    affinity = torch.zeros(2, 4, 4, dtype=torch.bool)
    affinity[:, 0, 1] = affinity[:, 1, 0] = True  # consistent positive pair (0, 1)
    cos = torch.zeros(2, 4, 4)
    cos[1, 0, 1] = 0.5  # below 0.75 at one scale: hard positive
    cos[0, 2, 3] = 0.6  # above 0.5 on a negative: hard negative
    draw = torch.ones(4, 4)  # never keep consistent pairs by chance
    pos, neg = mine_pairs(cos, affinity, draw)
    assert pos[0, 1] and not neg[0, 1]
    assert neg[2, 3] and not pos[2, 3]
    assert int(pos.sum()) == 1 and int(neg.sum()) == 1


def test_empty_pair_sets_give_norm_term_only():
    features = torch.tensor([[2.0, 0.0], [2.0, 0.0]])
    gates = torch.ones(1, 2)
    affinity = torch.ones(1, 2, 2, dtype=torch.bool)
    loss = contrastive_loss(features, gates, affinity, torch.ones(2, 2), torch.ones(2, 2))
    torch.testing.assert_close(loss, torch.tensor(1.0))  # (1 - 2)^2, pair terms empty


def _reference_mining(
    cos: torch.Tensor,
    affinity: torch.Tensor,
    draw: torch.Tensor,
    pos_thr: float = 0.75,
    neg_thr: float = 0.5,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Pair mining written as in SAGA (sum of G over scales, any over scales)."""
    t, s, _ = affinity.shape
    z = affinity.sum(0)
    cons_pos, cons_neg = z == t, z == 0
    inconsistent = ~(cons_pos | cons_neg)
    half = inconsistent.sum() / 2
    keep_pos = cons_pos & (draw < half / cons_pos.sum().clamp(min=1))
    keep_neg = cons_neg & (draw < half / cons_neg.sum().clamp(min=1))
    hard_pos = (affinity & (cos < pos_thr)).any(0)
    hard_neg = (~affinity & (cos > neg_thr)).any(0)
    upper = torch.ones(s, s, dtype=torch.bool).triu(1)
    return (keep_pos | hard_pos | inconsistent) & upper, (
        keep_neg | hard_neg | inconsistent
    ) & upper


def test_mine_pairs_matches_reference():
    for seed in range(10):
        _, _, affinity, _, draw = _inputs(s=30, t=5, seed=seed)
        g = torch.Generator().manual_seed(seed)
        cos = torch.rand(5, 30, 30, generator=g, dtype=torch.float64) * 2 - 1
        cos = (cos + cos.transpose(1, 2)) / 2
        for got, want in zip(
            mine_pairs(cos, affinity, draw), _reference_mining(cos, affinity, draw), strict=True
        ):
            assert torch.equal(got, want)


def test_cpu_kernels_match_the_torch_expressions():
    from dcseg.affinity import kernels
    from dcseg.affinity.loss import coefficients_torch, extremes_torch

    g = torch.Generator().manual_seed(4)
    for dtype in (torch.float32, torch.float64):
        cos = torch.rand(3, 7, 9, generator=g, dtype=dtype) * 2 - 1
        cos[0, 0, 0] = 0.0  # on the C > 0 switch
        affinity = torch.rand(3, 7, 9, generator=g) < 0.4
        a, b = (
            torch.rand(7, 9, generator=g, dtype=dtype),
            torch.rand(7, 9, generator=g, dtype=dtype),
        )
        low, high = torch.empty(7, 9, dtype=dtype), torch.empty(7, 9, dtype=dtype)
        kernels.pair_extremes(cos.numpy(), affinity.numpy(), 4.0, low.numpy(), high.numpy())
        want_low, want_high = torch.empty_like(low), torch.empty_like(high)
        extremes_torch(cos, affinity, want_low, want_high)
        assert torch.equal(low, want_low) and torch.equal(high, want_high)
        coef = kernels.pair_coefficients(cos.numpy(), affinity.numpy(), a.numpy(), b.numpy())
        assert torch.equal(torch.from_numpy(coef), coefficients_torch(cos, affinity, a, b))


def _extremes_on_the_bounds(
    t: int, s: int, dtype: torch.dtype, pos_thr: float, neg_thr: float, seed: int
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Affinity, low, high and draw with pairs whose selection hangs on one bound each."""
    g = torch.Generator().manual_seed(seed)
    _, _, affinity, _, _ = _inputs(s=s, t=t, seed=seed)
    cos = torch.rand(t, s, s, generator=g, dtype=dtype) * 2 - 1
    shifted = torch.where(affinity, cos - 4.0, cos)
    low, high = shifted.amin(0).triu(1), shifted.amax(0).triu(1)
    draw = torch.rand(s, s, generator=g, dtype=dtype)
    bound = torch.tensor([pos_thr, neg_thr], dtype=dtype)
    low[0, 1:4], high[0, 1:4], draw[0, 1:4] = bound[0] - 4.0, -3.5, math.inf  # on the bound
    low[1, 2:5], high[1, 2:5], draw[1, 2:5] = -0.99, bound[1], math.inf  # on the bound
    low[2, 3:9] = high[2, 3:9] = -3.01  # consistent positives, not hard: kept by the draw
    low[3, 4:10] = high[3, 4:10] = -1.5  # consistent negatives, not hard
    all_pos, all_neg = high < -2.0, low > -2.0
    upper = torch.ones(s, s, dtype=torch.bool).triu(1)
    diagonal = torch.diagonal(affinity, dim1=1, dim2=2)
    half = int((~(all_pos | all_neg) & upper).sum())
    for row, chosen, diag in ((2, all_pos, diagonal.all(0)), (3, all_neg, (~diagonal).all(0))):
        n = 2 * int((chosen & upper).sum()) + int(diag.sum())
        ratio = torch.tensor(half / max(n, 1), dtype=torch.float32).to(dtype)
        near = torch.stack([ratio, ratio.nextafter(ratio + 1), ratio.nextafter(ratio - 1)])
        draw[row, row + 1 : row + 7] = near.repeat(2)
    return affinity, low, high, draw


def test_cpu_pair_set_weights_equal_the_torch_selection():
    from dcseg.affinity.loss import _Mining, _pair_scales, _pair_set_weights_cpu, _select

    g = torch.Generator().manual_seed(7)
    for dtype in (torch.float32, torch.float64):
        for seed, (pos_thr, neg_thr) in enumerate([(0.75, 0.5), (0.7, 0.45), (0.1, -0.5)]):
            t, s = 4, 37
            affinity, low, high, draw = _extremes_on_the_bounds(t, s, dtype, pos_thr, neg_thr, seed)
            weights = 1.0 + 9.0 * torch.rand(s, s, generator=g, dtype=dtype)
            mining = _Mining(affinity, weights, draw, pos_thr, neg_thr, 8)
            pos, neg = _select(low, high, affinity, draw, pos_thr, neg_thr)
            assert pos.any() and neg.any()
            want = _pair_scales(weights, pos, neg, t)
            got = _pair_set_weights_cpu(low, high, mining, t)
            for a, b in zip(got, want, strict=True):
                assert a.dtype == dtype and torch.equal(a, b)
