import tracemalloc

import numpy as np

from dcseg.affinity.targets import (
    PackedMasks,
    build_batch,
    membership,
    pack_masks,
    pair_affinity,
    pair_weights,
    sample_pixels,
    sample_scale_indices,
    sample_scales,
)
from tests.scenes.affinity import camera_matrix, encode


def _packed(dense: np.ndarray, scales: np.ndarray) -> PackedMasks:
    """PackedMasks straight from a dense stack and given (descending) scales."""
    m, h, w = dense.shape
    bits = np.stack([np.packbits(d.ravel()) for d in dense])
    covered = np.bitwise_or.reduce(bits, axis=0)
    return PackedMasks(
        h, w, scales, dense.reshape(m, -1).sum(1).astype(float), bits, covered,
        int(dense.any(0).sum()),
    )  # fmt: skip


def _nested() -> np.ndarray:
    """big (cols 0-11) contains small (cols 0-3); other (cols 12-15) is separate and tiniest."""
    dense = np.zeros((3, 8, 16), dtype=bool)
    dense[0, :, :12] = True
    dense[1, :, :4] = True
    dense[2, :, 12:] = True
    return dense


def test_pack_masks_sorts_by_scale_and_drops_unmeasurable():
    dense = np.zeros((3, 48, 64), dtype=bool)
    dense[0, 10:20, 10:20] = True  # medium
    dense[1, 5:45, 5:60] = True  # large
    dense[2, 30, 30] = True  # one pixel: no scale, dropped
    depth = np.full((48, 64), 2.0, dtype=np.float32)
    packed = pack_masks(encode(dense), depth, camera_matrix())
    assert packed is not None and len(packed) == 2
    assert packed.scales[0] > packed.scales[1]
    np.testing.assert_array_equal(packed.areas, [dense[1].sum(), dense[0].sum()])
    assert packed.bits.shape == (2, 48 * 64 // 8) and packed.bits.dtype == np.uint8
    assert packed.n_covered == int((dense[0] | dense[1]).sum())
    assert pack_masks(encode(dense[2:]), depth, camera_matrix()) is None


def test_membership_matches_dense_masks():
    rng = np.random.default_rng(0)
    dense = rng.random((5, 13, 11)) < 0.3  # H*W not a multiple of 8
    packed = _packed(dense, np.arange(5, 0, -1.0))
    pixels = np.arange(13 * 11)
    np.testing.assert_array_equal(membership(packed, pixels), dense.reshape(5, -1).T)


def test_sample_pixels_are_distinct_covered_pixels():
    rng = np.random.default_rng(0)
    dense = _nested()[2:]  # 32 covered pixels
    packed = _packed(dense, np.array([1.0]))
    pixels = sample_pixels(packed, 10, rng)
    assert pixels.shape == (10,) and np.unique(pixels).size == 10
    assert dense.reshape(-1)[pixels].all()
    assert sample_pixels(packed, 1000, rng).shape == (32,)  # capped at the covered count


def test_exclusive_smallest_mask_rule():
    dense = _nested()
    p_small, p_big, p_other = 0 * 16 + 1, 0 * 16 + 8, 0 * 16 + 14
    member = membership(
        _packed(dense, np.array([3.0, 1.0, 0.5])), np.array([p_small, p_big, p_other])
    )
    # cut 1: masks 0..1 (big, small) exclusive -> small's pixels leave big
    # cut 0: only big among 0..0 -> big intact, small-mask pixels join big-only pixels
    # cut -1: upper bound -> original masks
    g = pair_affinity(member, np.array([1, 0, -1, 2]))
    assert not g[0, 0, 1]  # scale of the small mask: small vs big-only are negative
    assert g[1, 0, 1]  # between small and big: one object
    assert g[2, 0, 1]  # upper bound: share the original big mask
    assert not g[:, 0, 2].any() and not g[:, 1, 2].any()  # "other" never joins them
    assert g[:, np.arange(3), np.arange(3)].all()  # every covered pixel is its own positive
    assert (g == g.transpose(0, 2, 1)).all()


def test_masks_below_the_cut_stay_unchanged():
    # two overlapping masks: A (scale 2) and B (scale 1) share pixel q
    dense = np.zeros((2, 1, 8), dtype=bool)
    dense[0, 0, :5] = True
    dense[1, 0, 3:] = True
    member = membership(_packed(dense, np.array([2.0, 1.0])), np.array([0, 4, 7]))
    g = pair_affinity(member, np.array([0, 1]))
    assert g[0, 1, 2]  # cut 0: B (below the cut) kept whole -> q ~ B-only pixel
    assert g[0, 0, 1]  # and A intact -> q ~ A-only pixel
    assert g[1, 1, 2] and not g[1, 0, 1]  # cut 1: q owned by B only


def test_pair_weights_range_and_order():
    dense = _nested()
    packed = _packed(dense, np.array([3.0, 1.0, 0.5]))
    pixels = np.array([1, 8, 14, 17, 30])
    w = pair_weights(membership(packed, pixels), packed.areas)
    assert w.dtype == np.float32 and w.shape == (5, 5)
    assert w.min() == 1.0 and w.max() == 10.0
    np.testing.assert_allclose(w, w.T)
    # a(p): pixel 8 is in big only (area 96), pixel 14 in other only (area 32)
    assert w[2, 2] == 10.0 and w[1, 1] == 1.0
    assert (pair_weights(membership(packed, np.array([8, 9])), packed.areas) == 1).all()


def test_scale_indices():
    rng = np.random.default_rng(0)
    idx = sample_scale_indices(20, 8, rng)
    assert idx.shape == (10,) and idx[0] == -1 and idx[-1] == 19
    assert np.unique(idx[1:9]).size == 8 and (idx[1:9] < 20).all()
    few = sample_scale_indices(3, 8, rng)
    assert sorted(few[1:4].tolist()) == [0, 1, 2] and (few[4:9] == 0).all()


def test_scale_sampling_ranges():
    rng = np.random.default_rng(0)
    scales = np.array([5.0, 3.0, 2.0, 0.5])  # view holds the global max U = 5
    upper, second = 5.0, 3.0
    for _ in range(200):
        idx = np.array([-1, 0, 1, 2, 3])
        sigma, cut = sample_scales(scales, idx, upper, rng)
        np.testing.assert_array_equal(cut, [-1, -1, 1, 2, 3])
        assert second <= sigma[0] < 2 * upper
        assert second <= sigma[1] <= upper  # mask at U is an upper-bound sample
        assert 2.0 <= sigma[2] <= 3.0 and 0.5 <= sigma[3] <= 2.0 and 0.0 <= sigma[4] <= 0.5
    sigma, cut = sample_scales(np.array([5.0]), np.array([-1, 0]), 5.0, rng)
    assert (cut == -1).all() and (sigma >= 0).all()  # no scale below U: floor 0


def test_no_dense_mask_stack_per_step():
    """Peak numpy memory of a step stays far below one dense M x H x W bool stack."""
    rng = np.random.default_rng(0)
    m, h, w = 64, 512, 512
    bits = np.packbits(rng.random((m, h * w)) < 0.2, axis=1)
    covered = np.bitwise_or.reduce(bits, axis=0)
    scales = np.sort(rng.random(m))[::-1].copy()
    packed = PackedMasks(h, w, scales, np.full(m, 1000.0), bits, covered, h * w)
    tracemalloc.start()
    try:
        batch = build_batch(packed, float(scales[0]), 256, 8, 10.0, rng)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert batch.affinity.shape == (10, 256, 256)
    assert peak < m * h * w // 4, f"peak {peak} bytes"


def _saga_affinity(member: np.ndarray, cut: np.ndarray) -> np.ndarray:
    """SAGA's construction (mask stack made exclusive row by row), as a test oracle."""
    stack = member.T.astype(bool)  # [M, S]
    out = []
    for j in cut:
        if j < 0:
            vec = stack
        else:
            vec = np.zeros_like(stack)
            vec[: j + 1] = stack[: j + 1]
            for k in range(j, -1, -1):
                vec[k] = vec[k] & ~vec[k + 1 :].any(axis=0)
            vec[j + 1 :] = stack[j + 1 :]
        out.append((vec.T.astype(int) @ vec.astype(int)) > 0)
    return np.stack(out)


def _saga_weights(member: np.ndarray, areas: np.ndarray) -> np.ndarray:
    mean = (member * areas).sum(1) / (member.sum(1) + 1e-9)
    size = mean[:, None] * mean[None, :]
    peak = size.max()
    size[size == 0] = 1e10
    rho = np.maximum(peak / size, 1.0)
    out: np.ndarray = (rho - rho.min()) / (rho.max() - rho.min()) * 9.0 + 1.0
    return out


def test_affinity_and_weights_match_saga_construction():
    rng = np.random.default_rng(0)
    for m in (3, 70):  # one and two 64-bit words
        member = rng.random((40, m)) < 0.15
        member[:, 0] |= rng.random(40) < 0.5
        member[0] = False  # a pixel in no mask
        cut = np.concatenate([[-1], rng.integers(0, m, 8), [m - 1]])
        np.testing.assert_array_equal(pair_affinity(member, cut), _saga_affinity(member, cut))
        areas = rng.integers(10, 5000, m).astype(float)
        np.testing.assert_allclose(
            pair_weights(member, areas), _saga_weights(member, areas), rtol=1e-5
        )
