import dataclasses
import subprocess
import sys

import numpy as np
import pytest
import torch

import dcseg.affinity
from dcseg.affinity import AffinityView, gated_features, train_affinity
from dcseg.affinity.config import PRESETS, AffinityConfig
from dcseg.affinity.knn import knn_indices, smooth_features
from dcseg.affinity.targets import PackedMasks
from dcseg.affinity.train import _blend_pixels, _view_order, render_smoothed
from tests.scenes.affinity import synthetic_scene
from tests.scenes.blends import blend_from_lists


@pytest.fixture
def one_thread():
    """Single-threaded torch: the loop's small ops are faster and timings stable on shared CPUs."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


def _block_cosines(h: torch.Tensor, group: np.ndarray) -> np.ndarray:
    """Min cosine within each object (diagonal) and max cosine across objects (off-diagonal)."""
    c = (h @ h.T).numpy()
    k = int(group.max()) + 1
    out = np.zeros((k, k))
    for a in range(k):
        for b in range(k):
            block = c[group == a][:, group == b]
            out[a, b] = block.min() if a == b else block.max()
    return out


def test_end_to_end_separates_objects_by_scale(one_thread):
    scene = synthetic_scene(seed=0)
    cfg = AffinityConfig(iterations=300, rays=400, seed=0)
    result = train_affinity(scene.gaussians, scene.views, cfg)
    n = len(scene.gaussians)
    assert result.features.shape == (n, 32) and result.gate_weight.shape == (32, 1)
    assert result.gate_bias.shape == (32,) and len(result.losses) == 300
    assert result.scale_quantiles.shape == (16,)  # 4 masks x 4 views
    assert np.mean(result.losses[-20:]) < np.mean(result.losses[:20])

    small = _block_cosines(gated_features(result, 0.1), scene.group)
    assert np.diag(small).min() > 0.9
    assert small[~np.eye(3, dtype=bool)].max() < 0.5

    large = _block_cosines(gated_features(result, 1.0), scene.group)
    assert np.diag(large).min() > 0.9
    assert large[1, 2] > 0.9  # the group mask joins objects 1 and 2 at large scale
    assert large[0, 1] < 0.5 and large[0, 2] < 0.5


def test_seeded_and_reports_progress(one_thread):
    scene = synthetic_scene(seed=1, n_views=2)
    cfg = AffinityConfig(iterations=5, rays=64, feature_dim=8, seed=3)
    calls = []
    a = train_affinity(scene.gaussians, scene.views, cfg, on_progress=lambda *x: calls.append(x))
    b = train_affinity(scene.gaussians, scene.views, cfg)
    assert a.losses == b.losses
    torch.testing.assert_close(a.features, b.features)
    assert [c[:2] for c in calls] == [(i, 5) for i in range(1, 6)]
    assert [c[2] for c in calls] == list(a.losses)


def test_views_without_masks_are_skipped():
    scene = synthetic_scene(seed=2, n_views=2)
    empty = dataclasses.replace(scene.views[0], masks=None)
    cfg = AffinityConfig(iterations=2, rays=32, feature_dim=4)
    result = train_affinity(scene.gaussians, [empty, scene.views[1]], cfg)
    assert result.scale_quantiles.shape == (4,)
    no_depth = dataclasses.replace(scene.views[1], depth=np.zeros_like(scene.views[1].depth))
    with pytest.raises(ValueError, match="no view has masks"):
        train_affinity(scene.gaussians, [empty, no_depth], cfg)


def test_zero_iterations_returns_smoothed_initial_features():
    scene = synthetic_scene(seed=0, n_views=1)
    result = train_affinity(scene.gaussians, scene.views, AffinityConfig(iterations=0))
    assert result.losses == () and result.features.shape == (len(scene.gaussians), 32)
    assert (result.features.norm(dim=-1) <= 1.0 + 1e-6).all()


def test_quantile_scale_of_result():
    scene = synthetic_scene(seed=0, n_views=1)
    result = train_affinity(scene.gaussians, scene.views, AffinityConfig(iterations=0))
    grid = result.scale_quantiles
    assert result.quantile_scale(float(grid[0]) / 2) == 0.0
    assert result.quantile_scale(float(grid[-1]) * 2) == 1.0


def test_mask_pixels_map_to_blend_pixels_by_nearest_centre():
    packed = PackedMasks(
        4, 6, np.ones(1), np.ones(1), np.zeros((1, 3), np.uint8), np.zeros(3, np.uint8), 0
    )
    blend = blend_from_lists(8, 12, {})
    pixels = np.array([0, 5, 6 * 3 + 5])  # (0,0), (0,5), (3,5) at 4x6
    got = _blend_pixels(pixels, packed, blend).tolist()
    assert got == [1 * 12 + 1, 1 * 12 + 11, 7 * 12 + 11]


def test_config_validation_and_presets():
    assert PRESETS["paper"].iterations == 10_000 and PRESETS["paper"].feature_dim == 32
    assert PRESETS["paper"].rays == 1000 and PRESETS["paper"].knn_k == 16
    fast, paper = PRESETS["fast"], PRESETS["paper"]
    assert (fast.iterations, fast.lr) == (1000, 2 * paper.lr)  # measured, see FAST's docstring
    assert dataclasses.replace(fast, iterations=paper.iterations, lr=paper.lr) == paper
    with pytest.raises(ValueError, match="knn_sample"):
        AffinityConfig(knn_k=4, knn_sample=8)
    with pytest.raises(ValueError, match="rays"):
        AffinityConfig(rays=0)


def test_exports_sorted_and_complete():
    assert dcseg.affinity.__all__ == sorted(dcseg.affinity.__all__)
    assert set(dcseg.affinity.__all__) == {
        "AffinityResult",
        "AffinityView",
        "gated_features",
        "mask_scales",
        "train_affinity",
    }
    assert AffinityView.__dataclass_params__.frozen  # type: ignore[attr-defined]


def test_config_does_not_import_torch():
    code = "import sys, dcseg.affinity.config; assert 'torch' not in sys.modules"
    subprocess.run([sys.executable, "-c", code], check=True)


def test_sparse_render_matches_blend_gather():
    scene = synthetic_scene(seed=0, n_views=1)
    blend = scene.views[0].weights()
    knn = knn_indices(scene.gaussians.means, 16)
    slots = torch.tensor([0, 2, 5, 7, 9, 11, 13, 15])
    pixels = torch.tensor([0, 10 * 64 + 5, 15 * 64 + 25, 20 * 64 + 45, 47 * 64 + 63])
    feats = torch.randn(len(scene.gaussians), 6, dtype=torch.float64, requires_grad=True)
    got = render_smoothed(blend, pixels, feats, knn, slots)
    (got * torch.arange(6.0)).sum().backward()  # type: ignore[no-untyped-call]
    assert feats.grad is not None
    grad = feats.grad.clone()
    feats.grad = None
    want = blend.gather(smooth_features(feats, knn, None, slots), pixels)
    (want * torch.arange(6.0)).sum().backward()  # type: ignore[no-untyped-call]
    torch.testing.assert_close(got, want)
    torch.testing.assert_close(grad, feats.grad)
    assert got[0].abs().sum() == 0  # background pixel: nothing blended


def test_views_are_drawn_without_replacement_per_epoch():
    order = _view_order(5, 23, np.random.default_rng(0))
    assert len(order) == 23
    for epoch in range(4):
        assert sorted(order[5 * epoch : 5 * epoch + 5]) == list(range(5))
