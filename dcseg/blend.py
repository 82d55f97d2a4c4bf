"""Per-view blending weights of frozen Gaussians: render anything without re-rasterising.

Once geometry and opacity are frozen (affinity training, cluster masks, label images), every
pixel's colour is a fixed linear combination of per-Gaussian values:
``out(p) = sum_i w_pi * v_i`` with ``w_pi = alpha_pi * T_pi``. :class:`BlendWeights` stores those
weights for one view in CSR form (one row per pixel, row-major pixel order ``p = v * W + u``),
truncated where the remaining transmittance is negligible, so feature rendering at a few sampled
pixels, one-hot cluster rendering for all clusters at once and label images are sparse products.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

DENSE_BUDGET = 1 << 22
"""Largest ``pixels x groups`` table :meth:`BlendWeights.dominant_group` fills per block (16 MB
in float32)."""


@dataclass(frozen=True)
class BlendWeights:
    """The blending weights of one view, CSR over pixels.

    Attributes:
        height, width: the view's resolution.
        offsets: ``[H*W + 1]`` int64; the contributions of pixel ``p`` are
            ``ids[offsets[p]:offsets[p+1]]`` with ``weights[offsets[p]:offsets[p+1]]``.
        ids: ``[nnz]`` int32 or int64 Gaussian indices, front to back within a pixel.
        weights: ``[nnz]`` float32 blending weights ``alpha * T``.
    """

    height: int
    width: int
    offsets: Tensor
    ids: Tensor
    weights: Tensor

    def __post_init__(self) -> None:
        if self.offsets.shape != (self.height * self.width + 1,):
            raise ValueError(
                f"offsets must have shape ({self.height * self.width + 1},), "
                f"got {tuple(self.offsets.shape)}"
            )
        if self.ids.shape != self.weights.shape or self.ids.ndim != 1:
            raise ValueError("ids and weights must be 1-D tensors of the same length")

    @property
    def nnz(self) -> int:
        return int(self.ids.shape[0])

    def nbytes(self) -> int:
        """Memory held by the three tensors."""
        tensors = (self.offsets, self.ids, self.weights)
        return sum(t.element_size() * t.numel() for t in tensors)

    def rows(self) -> Tensor:
        """``[nnz]`` the pixel index of every stored contribution."""
        counts = self.offsets[1:] - self.offsets[:-1]
        pixels = torch.arange(self.height * self.width, device=self.offsets.device)
        return torch.repeat_interleave(pixels, counts)

    def gather(self, values: Tensor, pixels: Tensor) -> Tensor:
        """Blend per-Gaussian values at some pixels; differentiable in ``values``.

        Args:
            values: ``[N, C]`` per-Gaussian values.
            pixels: ``[S]`` flat pixel indices ``v * W + u``.

        Returns:
            ``[S, C]`` blended values at those pixels.
        """
        starts, ends = self.offsets[pixels], self.offsets[pixels + 1]
        counts = ends - starts
        row = torch.repeat_interleave(torch.arange(pixels.shape[0], device=pixels.device), counts)
        first = torch.repeat_interleave(starts - torch.cumsum(counts, 0) + counts, counts)
        entry = first + torch.arange(row.shape[0], device=pixels.device)
        ids = self.ids[entry]
        contrib = values.index_select(0, ids) * self.weights[entry, None].to(values.dtype)
        out = values.new_zeros((pixels.shape[0], values.shape[1]))
        return out.index_add(0, row, contrib)

    def render(self, values: Tensor) -> Tensor:
        """Blend per-Gaussian values at every pixel: ``[N, C]`` -> ``[H, W, C]``."""
        contrib = values.index_select(0, self.ids) * self.weights[:, None].to(values.dtype)
        out = values.new_zeros((self.height * self.width, values.shape[1]))
        out = out.index_add(0, self.rows(), contrib)
        return out.reshape(self.height, self.width, values.shape[1])

    def accumulate_groups(self, group: Tensor, n_groups: int) -> Tensor:
        """Per pixel and group, the summed weight of the group's Gaussians.

        Args:
            group: ``[N]`` int64 group (e.g. cluster) of every Gaussian, ``-1`` = none.
            n_groups: number of groups K.

        Returns:
            ``[H, W, K]`` accumulated blending weight of each group; this is the one-hot render
            of all groups at once.
        """
        g = group[self.ids]
        keep = g >= 0
        flat = self.rows()[keep] * n_groups + g[keep]
        out = torch.zeros(self.height * self.width * n_groups, dtype=self.weights.dtype)
        out = out.to(self.weights.device).index_add(0, flat, self.weights[keep])
        return out.reshape(self.height, self.width, n_groups)

    def dominant_group(self, group: Tensor, min_weight: float) -> Tensor:
        """Per pixel, the group with the largest accumulated weight, if at least ``min_weight``.

        One pass for all groups, never an ``[H, W, K]`` table: on the CPU a numba kernel
        (O(nnz), ~10 ms for 2M contributions), elsewhere :meth:`dominant_group_blocks`. Ties go
        to the lower group index; pixels without a contribution from any group stay -1.

        Args:
            group: ``[N]`` int64 group (e.g. cluster) of every Gaussian, ``-1`` = none.
            min_weight: smallest accumulated weight that claims a pixel.

        Returns:
            ``[H, W]`` int64 group per pixel, ``-1`` = none.
        """
        if self.ids.device.type != "cpu":
            return self.dominant_group_blocks(group, min_weight)
        from dcseg.blend_kernels import dominant_group

        groups = group.detach().cpu().long().numpy()
        largest = int(self.ids.max()) if self.nnz else -1
        if groups.shape[0] <= largest:
            raise IndexError(f"group has {groups.shape[0]} entries but ids go up to {largest}")
        n_groups = max(int(groups.max(initial=-1)) + 1, 1)
        weights = self.weights.detach().numpy()
        floor = float(np.asarray(min_weight, dtype=weights.dtype))  # compared as PyTorch does
        offsets, ids = self.offsets.numpy(), self.ids.numpy()
        out = dominant_group(offsets, ids, weights, groups, n_groups, floor)
        return torch.from_numpy(out).reshape(self.height, self.width)

    def dominant_group_blocks(self, group: Tensor, min_weight: float) -> Tensor:
        """:meth:`dominant_group` in PyTorch (any device): blocks of pixels accumulate into a
        dense ``[pixels, K]`` table of at most :data:`DENSE_BUDGET` entries (bounded memory)."""
        n_pixels = self.height * self.width
        out = torch.full((n_pixels,), -1, dtype=torch.int64, device=self.ids.device)
        g = group.to(self.ids.device)[self.ids.long()]
        if not bool((g >= 0).any()):
            return out.reshape(self.height, self.width)
        n_groups = int(g.max()) + 1
        rows = self.rows()
        block = max(1, DENSE_BUDGET // n_groups)
        for start in range(0, n_pixels, block):
            stop = min(start + block, n_pixels)
            lo, hi = int(self.offsets[start]), int(self.offsets[stop])
            members = g[lo:hi]
            keep = members >= 0
            keys = (rows[lo:hi][keep] - start) * n_groups + members[keep]
            size = (stop - start) * n_groups
            table = torch.zeros(size, dtype=self.weights.dtype, device=g.device)
            table = table.index_add(0, keys, self.weights[lo:hi][keep]).view(-1, n_groups)
            best, winner = table.max(dim=1)  # first maximum = lowest group index
            claimed = (best >= min_weight) & (best > 0)
            out[start:stop] = torch.where(claimed, winner, out[start:stop])
        return out.reshape(self.height, self.width)
