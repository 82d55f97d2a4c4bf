import numpy as np
import torch

from dcseg.affinity.knn import (
    NeighbourMean,
    knn_indices,
    neighbour_mean_torch,
    sample_slots,
    smooth_features,
)


def _two_clusters(n: int = 20, d: int = 4, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    means = torch.cat(
        [torch.randn(n, 3, generator=g) * 0.1, torch.randn(n, 3, generator=g) * 0.1 + 10]
    )
    features = torch.randn(2 * n, d, generator=g)
    return means, features


def test_knn_includes_self_first_and_clamps_k():
    means, _ = _two_clusters()
    knn = knn_indices(means, 16)
    assert knn.shape == (40, 16) and knn.dtype == torch.int64
    assert (knn[:, 0] == torch.arange(40)).all()
    assert ((knn < 20).all(1) == (torch.arange(40) < 20)).all()  # neighbours stay in the cluster
    assert knn_indices(means[:5], 16).shape == (5, 5)


def test_final_smoothing_uses_all_neighbours_without_renormalising():
    means, features = _two_clusters(n=16)
    knn = knn_indices(means, 16)
    out = smooth_features(features, knn, renormalize=False)
    unit = torch.nn.functional.normalize(features, dim=-1)
    torch.testing.assert_close(out[:16], unit[:16].mean(0).expand(16, -1))
    torch.testing.assert_close(out[16:], unit[16:].mean(0).expand(16, -1))
    assert (out.norm(dim=-1) < 1).all()


def test_training_smoothing_uses_the_same_slots_and_renormalises():
    means, features = _two_clusters()
    knn = knn_indices(means, 16)
    slots = sample_slots(16, 8, np.random.default_rng(0))
    assert slots.shape == (8,) and torch.unique(slots).numel() == 8
    rows = torch.tensor([0, 5, 33])
    out = smooth_features(features, knn, rows, slots)
    unit = torch.nn.functional.normalize(features, dim=-1)
    want = torch.nn.functional.normalize(unit[knn[rows][:, slots]].mean(1), dim=-1)
    torch.testing.assert_close(out, want)
    torch.testing.assert_close(out.norm(dim=-1), torch.ones(3))
    full = smooth_features(features, knn, None, slots)
    torch.testing.assert_close(full[rows], out)


def test_smoothing_is_differentiable():
    means, features = _two_clusters()
    features.requires_grad_(True)
    knn = knn_indices(means, 16)
    out = smooth_features(features, knn, torch.tensor([0]), torch.tensor([0, 3]))
    out.sum().backward()  # type: ignore[no-untyped-call]
    assert features.grad is not None
    touched = (features.grad.abs().sum(1) > 0).nonzero().ravel()
    assert set(touched.tolist()) <= set(knn[0, [0, 3]].tolist())


def _neighbour_case(dtype: torch.dtype) -> tuple[torch.Tensor, torch.Tensor]:
    means, features = _two_clusters(n=30, d=5, seed=3)
    features = features.to(dtype)
    features[7] = 0.0  # a zero feature: the normalisation's clamp branch
    features[9] *= 1e-14  # below the norm floor too
    knn = knn_indices(means, 8)
    rows = torch.tensor([0, 7, 9, 12, 31, 45, 7])  # a repeated row shares its neighbours
    return features, knn[rows][:, [0, 2, 5, 7]]


def test_numba_neighbour_mean_matches_torch_values_and_gradients():
    for dtype, tol in ((torch.float64, 1e-12), (torch.float32, 1e-5)):
        features, neighbours = _neighbour_case(dtype)
        weights = torch.randn(neighbours.shape[0], 5, generator=torch.Generator().manual_seed(1))
        grads = []
        for fn in (NeighbourMean.apply, neighbour_mean_torch):
            x = features.clone().requires_grad_(True)
            out = fn(x, neighbours)
            (out * weights.to(dtype)).sum().backward()
            grads.append((out.detach(), x.grad))
        torch.testing.assert_close(grads[0][0], grads[1][0], atol=tol, rtol=tol)
        torch.testing.assert_close(grads[0][1], grads[1][1], atol=tol * 1e3, rtol=tol)


def test_numba_neighbour_mean_passes_gradcheck():
    features, neighbours = _neighbour_case(torch.float64)
    features[7] = 0.3  # gradcheck needs a smooth point: no feature on the norm floor
    features[9] = -0.2
    x = features.clone().requires_grad_(True)

    def mean(f: torch.Tensor) -> torch.Tensor:
        out: torch.Tensor = NeighbourMean.apply(f, neighbours)  # type: ignore[no-untyped-call]
        return out

    assert torch.autograd.gradcheck(mean, (x,))
