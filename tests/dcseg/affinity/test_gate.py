import numpy as np
import pytest
import torch
from sklearn.preprocessing import QuantileTransformer

from dcseg.affinity.gate import ScaleGate, fit_quantiles, quantile_transform


@pytest.mark.parametrize("n", [7, 500, 3000])
def test_quantile_transform_matches_sklearn(n):
    rng = np.random.default_rng(n)
    scales = np.round(rng.lognormal(0.0, 1.0, n), 2)  # repeated values included
    probe = np.concatenate([scales, rng.lognormal(0.0, 1.5, 200), [0.0, 1e3]])
    sk = QuantileTransformer(n_quantiles=min(1000, n), output_distribution="uniform")
    want = sk.fit(scales[:, None]).transform(probe[:, None])[:, 0]
    got = quantile_transform(probe, fit_quantiles(scales))
    np.testing.assert_allclose(got, want, atol=1e-12)


def test_quantile_transform_monotone_and_clipped():
    grid = fit_quantiles(np.random.default_rng(0).random(100) + 1.0, n_quantiles=1000)
    assert grid.shape == (100,)
    x = np.linspace(0.0, 3.0, 1001)
    q = quantile_transform(x, grid)
    assert (np.diff(q) >= 0).all()
    assert q.min() == 0.0 and q.max() == 1.0
    assert (q[x <= grid[0]] == 0).all() and (q[x >= grid[-1]] == 1).all()


def test_fit_quantiles_ignores_nan_and_needs_a_value():
    assert fit_quantiles([3.0, np.nan, 1.0, 2.0]).tolist() == [1.0, 2.0, 3.0]
    with pytest.raises(ValueError, match="no finite scale"):
        fit_quantiles([np.nan])


def test_scale_gate_shape_range_and_seed():
    a = ScaleGate(32, torch.Generator().manual_seed(3))
    b = ScaleGate(32, torch.Generator().manual_seed(3))
    out = a(torch.tensor([0.0, 0.5, 1.0]))
    assert out.shape == (3, 32) and (out > 0).all() and (out < 1).all()
    torch.testing.assert_close(out, b(torch.tensor([0.0, 0.5, 1.0])))
    assert a.weight.shape == (32, 1) and a.bias.shape == (32,)
