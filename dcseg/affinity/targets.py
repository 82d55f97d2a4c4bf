"""Training targets for sampled pixels (method doc Part A §3.3), memory-bounded (Part B.3).

A view's masks are decoded once into :class:`PackedMasks`: one ``np.packbits`` row per mask
(``[M, ceil(H*W/8)]`` uint8, row-major pixels ``p = v * W + u``), sorted by 3D scale descending,
plus the packed union "covered by >= 1 mask". Each step then touches only the sampled pixels:
``membership`` reads one byte column per pixel (``[S, M]``), and every target (scale samples,
ground-truth affinity ``G_t(p, q)``, pair weights) is built from that ``[S, M]`` table. Nothing of
size ``M x H x W`` exists after packing; the largest per-step arrays are ``[T, S, S]`` and
``ceil(M/64)`` x ``[S, S]`` (``tests/dcseg/affinity/test_targets.py`` checks the peak with
tracemalloc).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from dcseg.affinity import kernels
from dcseg.affinity.scales import camera_points, decoded_masks, scale_of_mask
from dcseg.types import AgnosticMasks


@dataclass(frozen=True)
class PackedMasks:
    """One view's usable masks in compact form, sorted by 3D scale descending.

    Attributes:
        height, width: mask resolution.
        scales: ``[M]`` float64 3D scales, descending (masks without a scale are dropped).
        areas: ``[M]`` float64 pixel counts of the masks.
        bits: ``[M, ceil(H*W/8)]`` uint8, ``np.packbits`` of each row-major mask.
        covered: ``[ceil(H*W/8)]`` uint8, packed union of all masks.
        n_covered: number of covered pixels.
    """

    height: int
    width: int
    scales: NDArray[np.float64]
    areas: NDArray[np.float64]
    bits: NDArray[np.uint8]
    covered: NDArray[np.uint8]
    n_covered: int

    def __len__(self) -> int:
        return int(self.scales.shape[0])


@dataclass(frozen=True)
class Batch:
    """One step's targets for S sampled pixels and T scale samples.

    Attributes:
        pixels: ``[S]`` int64 flat pixel indices at mask resolution, ascending.
        scales: ``[T]`` float64 sampled 3D scales ``sigma_t`` (before quantile normalisation).
        affinity: ``[T, S, S]`` bool ground-truth affinity ``G_t(p, q)``.
        weights: ``[S, S]`` float32 pair weights in ``[1, max_weight]``.
        draw: ``[S, S]`` float32 uniform draws for subsampling consistent pairs.
    """

    pixels: NDArray[np.int64]
    scales: NDArray[np.float64]
    affinity: NDArray[np.bool_]
    weights: NDArray[np.float32]
    draw: NDArray[np.float32]


def pack_masks(
    masks: AgnosticMasks,
    depth: NDArray[np.float32],
    K: NDArray[np.float64],
    min_points: int = 10,
) -> PackedMasks | None:
    """Decode (one mask at a time), measure and pack a view's masks; None if none is usable.

    Masks with too few valid-depth points for a scale (NaN, see
    :func:`dcseg.affinity.scales.mask_scales`) are dropped: they give no target in this view.
    """
    points, valid = camera_points(depth, K, masks.height, masks.width)
    scales: list[float] = []
    rows: list[NDArray[np.uint8]] = []
    areas: list[float] = []
    for mask in decoded_masks(masks):
        scale = scale_of_mask(mask, points, valid, min_points)
        if np.isfinite(scale):
            scales.append(scale)
            rows.append(np.packbits(mask.ravel()))
            areas.append(float(mask.sum()))
    if not rows:
        return None
    order = np.argsort(-np.asarray(scales), kind="stable")
    bits = np.stack(rows)[order]
    covered = np.bitwise_or.reduce(bits, axis=0)
    n_covered = int(np.unpackbits(covered, count=masks.height * masks.width).sum())
    return PackedMasks(
        masks.height,
        masks.width,
        np.asarray(scales, dtype=np.float64)[order],
        np.asarray(areas, dtype=np.float64)[order],
        bits,
        covered,
        n_covered,
    )


def sample_pixels(packed: PackedMasks, n: int, rng: np.random.Generator) -> NDArray[np.int64]:
    """``[min(n, n_covered)]`` distinct covered pixels, uniformly at random, ascending."""
    covered = np.flatnonzero(np.unpackbits(packed.covered, count=packed.height * packed.width))
    chosen = rng.choice(covered.shape[0], size=min(n, covered.shape[0]), replace=False)
    return np.sort(covered[chosen]).astype(np.int64)


def membership(packed: PackedMasks, pixels: NDArray[np.int64]) -> NDArray[np.bool_]:
    """``[S, M]`` whether each sampled pixel lies in each (scale-sorted) mask."""
    byte = packed.bits[:, pixels >> 3]
    shift = (7 - (pixels & 7)).astype(np.uint8)
    return ((byte >> shift) & 1).astype(bool).T


def sample_scale_indices(
    n_masks: int, n_random: int, rng: np.random.Generator
) -> NDArray[np.int64]:
    """Mask indices of the ``n_random + 2`` scale samples (§3.3.1).

    ``[-1, r_1 .. r_n, M - 1]``: -1 marks the above-max sample, ``r_i`` are the first entries of a
    random permutation of the M masks (slots beyond M are 0, the largest mask, as in SAGA), and
    the last sample is the smallest mask.
    """
    random = np.zeros(n_random, dtype=np.int64)
    perm = rng.permutation(n_masks)[:n_random]
    random[: perm.shape[0]] = perm
    return np.concatenate([[-1], random, [n_masks - 1]]).astype(np.int64)


def sample_scales(
    scales: NDArray[np.float64],
    indices: NDArray[np.int64],
    upper: float,
    rng: np.random.Generator,
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Sampled 3D scales ``sigma_t`` and each sample's exclusivity cut (§3.3.1 and §3.3.4).

    Args:
        scales: ``[M]`` the view's mask scales, descending.
        indices: ``[T]`` from :func:`sample_scale_indices`.
        upper: U, the largest mask scale over all views.

    Returns:
        ``sigma [T]`` and ``cut [T]``: ``cut_t = j_t`` for a sample from mask j (masks ``0..j``
        are made mutually exclusive), ``-1`` for an upper-bound sample (``sigma_t >= U`` before
        jitter: the original masks are the target). Upper-bound samples fall uniformly between
        ``U (1 + u)`` (or U) and the view's largest scale below U (0 if none); a sample from mask
        j between ``s_j`` and ``s_{j+1}``; the smallest mask's between 0 and its scale.
    """
    below = scales[scales < upper]
    second = float(below.max()) if below.size else 0.0
    sigma = np.empty(indices.shape[0], dtype=np.float64)
    cut = indices.copy()
    for t, j in enumerate(indices):
        s = upper * (1.0 + rng.random()) if j < 0 else float(scales[j])
        if s >= upper:
            floor, cut[t] = second, -1
        elif j < scales.shape[0] - 1:
            floor = float(scales[j + 1])
        else:
            floor = 0.0
        sigma[t] = s - (s - floor) * rng.random()
    return sigma, cut


def pair_affinity(member: NDArray[np.bool_], cut: NDArray[np.int64]) -> NDArray[np.bool_]:
    """Ground-truth affinity ``[T, S, S]`` of the sampled pixels at each scale sample (§3.3.4).

    For ``cut_t = j >= 0`` every pixel keeps, among masks ``0..j``, only the smallest one that
    contains it (the exclusive owner ``e_t(p)``); masks ``j+1..M-1`` stay as they are. So
    ``G_t(p, q) = [e_t(p) = e_t(q) >= 0] or [p, q share a mask k > j]``. For ``cut_t = -1``
    (upper bound) this reduces to "p and q share any original mask".
    """
    s, m = member.shape
    if m == 0:
        return np.zeros((cut.shape[0], s, s), dtype=bool)
    index = np.where(member, np.arange(m), -1)
    owner_upto = np.maximum.accumulate(index, axis=1)  # [S, M] smallest mask among 0..j
    owner = np.ascontiguousarray(owner_upto[:, np.clip(cut, 0, m - 1)].T)  # [T, S]
    smaller = _pack_words(np.arange(m)[None, :] > cut[:, None])  # [T, W] masks k > cut_t
    out: NDArray[np.bool_] = kernels.pair_affinity(_pack_words(member), owner, smaller, cut)
    return out


def pair_weights(
    member: NDArray[np.bool_], areas: NDArray[np.float64], max_weight: float = 10.0
) -> NDArray[np.float32]:
    """``[S, S]`` pair weights favouring small masks (§3.3.3).

    ``a(p)`` = mean area of the masks containing p, ``m = a(p) a(q)``, ``rho = max(m) / m``
    (``m = 0``, a pixel in no mask, gives 1), min-max rescaled over all pairs to
    ``[1, max_weight]`` (all 1 when ``rho`` is constant, where SAGA would divide by zero).
    Since ``rho = c(p) c(q)`` with ``c = a_max / a``, this is one outer product.
    """
    count = member.sum(axis=1)
    mean_area = (member.astype(np.float64) @ areas) / np.maximum(count, 1)
    inside = mean_area > 0
    if not inside.any():
        return np.ones((member.shape[0],) * 2, dtype=np.float32)
    c = np.where(inside, mean_area.max() / np.where(inside, mean_area, 1.0), 0.0)
    rho_max = float(c.max()) ** 2
    if rho_max <= 1.0:
        return np.ones((member.shape[0],) * 2, dtype=np.float32)
    k = (max_weight - 1.0) / (rho_max - 1.0)
    root = (c * np.sqrt(k)).astype(np.float32)
    weights: NDArray[np.float32] = np.multiply.outer(root, root) + np.float32(1.0 - k)
    np.clip(weights, 1.0, max_weight, out=weights)  # float32 rounding at the ends
    if not inside.all():  # rho = 1 (weight 1) for pairs with a pixel in no mask
        weights[~inside, :] = 1.0
        weights[:, ~inside] = 1.0
    return weights


def build_batch(
    packed: PackedMasks,
    upper: float,
    rays: int,
    random_scales: int,
    max_weight: float,
    rng: np.random.Generator,
) -> Batch:
    """Sample pixels and scales of one view and build all targets for them."""
    pixels = sample_pixels(packed, rays, rng)
    member = membership(packed, pixels)
    indices = sample_scale_indices(len(packed), random_scales, rng)
    sigma, cut = sample_scales(packed.scales, indices, upper, rng)
    affinity = pair_affinity(member, cut)
    weights = pair_weights(member, packed.areas, max_weight)
    draw = rng.random((pixels.shape[0], pixels.shape[0]), dtype=np.float32)
    return Batch(pixels, sigma, affinity, weights, draw)


def _pack_words(bits: NDArray[np.bool_]) -> NDArray[np.uint64]:
    """``[R, M]`` bool -> ``[R, ceil(M/64)]`` uint64 with bit k of a row at word k // 64."""
    rows, m = bits.shape
    n_words = max(1, -(-m // 64))
    packed = np.zeros((rows, n_words * 8), dtype=np.uint8)
    if m:
        packed[:, : -(-m // 8)] = np.packbits(bits, axis=1, bitorder="little")
    return packed.view("<u8").astype(np.uint64)
