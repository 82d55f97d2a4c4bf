"""A run's trained state on disk, so later runs re-cluster or re-classify without training.

Layout under ``RUN/state/``::

    gaussians.ply        the frozen Gaussians (3DGS PLY layout)
    affinity.npz         features [N,D], gate_weight [D,1], gate_bias [D], scale_quantiles [Q],
                         losses [T]
    views.json           per view: name, width, height, K (3x3), c2w (4x4)
    views/<i>.npz        per view: blend weights (counts per pixel uint8, ids int32, weights
                         float16 or float32) and depth (float16 m); written while the cache
                         is built and read back one view at a time (the whole cache is never
                         in memory; depth is read only when a stage asks for it)
    semantic/            the class-aware maps the run used (for re-clustering)
    vocabulary.json      their vocabulary

Arrays are written with :func:`numpy.savez` (uncompressed: it is a cache read back whole) and
read straight from their offsets in the file (:func:`dcseg.io.npz.read_stored`).
Version 1 (``offsets`` int64 and float32 weights per view) is still read.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray

from dcseg.affinity.data import AffinityResult
from dcseg.blend import BlendWeights
from dcseg.errors import InputError
from dcseg.io.captures.jsonfields import JsonFields, load_json
from dcseg.io.folders import link_or_copy
from dcseg.io.npz import read_stored

STATE_VERSION = 2
READABLE_VERSIONS = (1, 2)
"""Versions :func:`load_views` reads (1 stored ``offsets`` int64 and float32 weights)."""


class BlendMemory:
    """Cached views' blending weights kept in memory up to a byte budget: a capture whose cache
    fits the budget is read from disk once; in a larger one the views are kept in the order
    they are first seen until the budget is full, and the rest are read on every access, so it
    holds the budget plus the view in use, however many frames it has.

    Keeping the first views instead of evicting the least recently used one suits the stages'
    access: segmentation scans the views in order, and a scan longer than the budget would
    find none of an LRU's views (each is evicted before the scan comes back to it), where this
    finds the budget's worth every time; affinity training draws views at random, where both
    policies hit the same share."""

    def __init__(self, budget_bytes: int) -> None:
        self.budget = budget_bytes
        self._items: dict[Path, BlendWeights] = {}
        self._bytes = 0

    @property
    def nbytes(self) -> int:
        """Bytes held now."""
        return self._bytes

    def get(self, path: Path, width: int, height: int) -> BlendWeights:
        """The weights of ``path`` (read from disk unless held)."""
        held = self._items.get(path)
        if held is not None:
            return held
        blend = _read_blend(path, width, height)
        self.put(path, blend)
        return blend

    def put(self, path: Path, blend: BlendWeights) -> None:
        """Hold ``blend`` for ``path`` if it fits in what the budget has left."""
        size = blend.nbytes()
        if path in self._items or self._bytes + size > self.budget:
            return
        self._items[path] = blend
        self._bytes += size


@dataclass(frozen=True)
class ViewState:
    """One view as the segmentation stages need it after training.

    The blending weights and the depth live either in memory or in a ``views/<i>.npz`` file of
    the cache (:func:`write_view`); :attr:`blend` and :attr:`depth` then read them on every
    access and nothing keeps them, so a stage that visits the views one by one holds one
    view's weights at a time, and no stage holds every view's depth.

    Attributes:
        name: the frame stem.
        K: ``[3, 3]`` intrinsics.
        c2w: ``[4, 4]`` camera-to-world pose.
        width, height: the view's resolution (of the blending weights and the depth).
        cached: the weights in memory, or None when they are read from ``source``.
        held_depth: the depth in memory, or None when it is read from ``source``.
        source: the view's cache file, or None for in-memory weights.
        memory: where weights read from ``source`` are kept within a budget (None = read on
            every access).
    """

    name: str
    K: NDArray[np.float64]
    c2w: NDArray[np.float64]
    width: int
    height: int
    cached: BlendWeights | None = None
    held_depth: NDArray[np.float32] | None = None
    source: Path | None = None
    memory: BlendMemory | None = field(default=None, compare=False, repr=False)

    def __post_init__(self) -> None:
        if (self.cached is None) == (self.source is None):
            raise ValueError("a view needs exactly one of cached weights or a source file")
        if self.source is None and self.held_depth is None:
            raise ValueError("a view with weights in memory needs its depth in memory")

    @classmethod
    def in_memory(
        cls,
        name: str,
        K: NDArray[np.float64],
        c2w: NDArray[np.float64],
        blend: BlendWeights,
        depth: NDArray[np.float32],
    ) -> ViewState:
        return cls(name, K, c2w, blend.width, blend.height, cached=blend, held_depth=depth)

    @property
    def blend(self) -> BlendWeights:
        """The view's blending weights (read from the cache file when not in memory)."""
        if self.cached is not None:
            return self.cached
        assert self.source is not None
        if self.memory is not None:
            return self.memory.get(self.source, self.width, self.height)
        return _read_blend(self.source, self.width, self.height)

    @property
    def depth(self) -> NDArray[np.float32]:
        """``[H, W]`` float32 capture depth (metres, 0 = invalid), for affinity scales and
        evaluation (read from the cache file when not in memory)."""
        if self.held_depth is not None:
            return self.held_depth
        assert self.source is not None
        depth: NDArray[np.float32] = _load_npz(self.source, ("depth",))["depth"].astype(np.float32)
        return depth

    def cache_bytes(self) -> int:
        """Bytes the view's weights take (on disk, or in memory)."""
        if self.source is not None:
            return self.source.stat().st_size
        assert self.cached is not None
        return self.cached.nbytes()


def write_view(
    path: Path, name: str, K: NDArray[np.float64], c2w: NDArray[np.float64],
    blend: BlendWeights, depth: NDArray[np.float32], memory: BlendMemory | None = None,
    half_weights: bool = True,
) -> ViewState:  # fmt: skip
    """Write one view's weights (counts per pixel, ids int32, weights float16 with
    ``half_weights`` else float32) and depth (float16) to ``path``; the returned view reads
    them back on use (kept in ``memory`` if given)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    offsets = blend.offsets.cpu().numpy()
    counts = np.diff(offsets)
    ids = blend.ids.cpu().numpy().astype(np.int32, copy=False)
    weights = blend.weights.cpu().numpy()
    np.savez(
        path,
        counts=counts.astype(_count_dtype(counts), copy=False),
        ids=ids,
        weights=weights.astype(np.float16 if half_weights else np.float32, copy=False),
        depth=depth.astype(np.float16),
    )
    if memory is not None:
        memory.put(path, _as_stored(blend, ids, half_weights))
    return ViewState(name, K, c2w, blend.width, blend.height, source=path, memory=memory)


def _as_stored(blend: BlendWeights, ids: NDArray[np.int32], half_weights: bool) -> BlendWeights:
    """``blend`` as reading its file back gives it: int32 ids and, with ``half_weights``,
    weights rounded as float16 storage rounds them. A view kept in memory then gives the same
    results as one read back, costs 4 bytes less per contribution, and the numba kernels see
    one id type (each type is a separate compilation)."""
    weights = blend.weights.cpu()
    if half_weights:
        weights = weights.to(torch.float16).to(torch.float32)
    offsets = blend.offsets.cpu()
    return BlendWeights(blend.height, blend.width, offsets, torch.from_numpy(ids), weights)


def _count_dtype(counts: NDArray[np.int64]) -> type[np.unsignedinteger[Any]]:
    """The smallest unsigned type that holds every per-pixel count."""
    top = int(counts.max()) if counts.size else 0
    for dtype in (np.uint8, np.uint16, np.uint32):
        if top <= np.iinfo(dtype).max:
            return dtype
    return np.uint64


def save_affinity(path: Path, result: AffinityResult) -> None:
    """Write the trained features and scale gate."""
    np.savez(
        path,
        features=result.features.detach().cpu().numpy(),
        gate_weight=result.gate_weight.detach().cpu().numpy(),
        gate_bias=result.gate_bias.detach().cpu().numpy(),
        scale_quantiles=result.scale_quantiles.detach().cpu().numpy(),
        losses=np.asarray(result.losses, dtype=np.float64),
    )


def load_affinity(path: Path) -> AffinityResult:
    """Read what :func:`save_affinity` wrote."""
    data = _load_npz(path, ("features", "gate_weight", "gate_bias", "scale_quantiles", "losses"))
    return AffinityResult(
        features=torch.from_numpy(data["features"]),
        gate_weight=torch.from_numpy(data["gate_weight"]),
        gate_bias=torch.from_numpy(data["gate_bias"]),
        scale_quantiles=torch.from_numpy(data["scale_quantiles"]),
        losses=tuple(float(v) for v in data["losses"]),
    )


def save_views(folder: Path, views: Sequence[ViewState]) -> None:
    """Write ``views.json`` and one ``views/<i>.npz`` per view (views already cached at that
    path are left as they are; others are linked, or written from memory)."""
    (folder / "views").mkdir(parents=True, exist_ok=True)
    meta = []
    for i, view in enumerate(views):
        target = folder / "views" / f"{i}.npz"
        if view.source is None:
            write_view(target, view.name, view.K, view.c2w, view.blend, view.depth, None, False)
        elif view.source.resolve() != target.resolve():
            link_or_copy(view.source, target)
        meta.append(
            {
                "name": view.name,
                "width": view.width,
                "height": view.height,
                "K": view.K.tolist(),
                "c2w": view.c2w.tolist(),
            }
        )
    body = {"version": STATE_VERSION, "views": meta}
    (folder / "views.json").write_text(json.dumps(body) + "\n", encoding="utf-8")


def load_views(folder: Path, memory: BlendMemory | None = None) -> list[ViewState]:
    """Read what :func:`save_views` wrote (the weights are read on use, kept in ``memory``)."""
    path = folder / "views.json"
    fields = JsonFields(str(path))
    body = fields.mapping(load_json(path, str(path)), "")
    fields.raise_if_any()
    assert body is not None
    if body.get("version") not in READABLE_VERSIONS:
        raise InputError.single(str(path), f"unsupported state version {body.get('version')}")
    metas = fields.array(fields.get(body, "views", ""), "views")
    fields.raise_if_any()
    assert metas is not None
    views = [_load_view(folder, i, meta, memory, fields) for i, meta in enumerate(metas)]
    fields.raise_if_any()
    return [view for view in views if view is not None]


def _load_view(
    folder: Path, index: int, item: Any, memory: BlendMemory | None, fields: JsonFields
) -> ViewState | None:
    """The view ``views[index]`` describes, or None with its problems added to ``fields``."""
    where = f"views[{index}]"
    meta = fields.mapping(item, where)
    if meta is None:
        return None
    name = fields.string(meta, "name", where)
    width, height = fields.integer(meta, "width", where), fields.integer(meta, "height", where)
    c2w = fields.matrix4(meta, "c2w", where)
    k = fields.matrix3(meta, "K", where)
    path = folder / "views" / f"{index}.npz"
    if not path.is_file():
        raise InputError.single(str(path), "the view's cached weights are missing")
    if name is None or width is None or height is None or c2w is None or k is None:
        return None
    return ViewState(name, k, c2w, width, height, source=path, memory=memory)


def _read_blend(path: Path, width: int, height: int) -> BlendWeights:
    """A view's weights from its file: ``counts`` (version 2) or ``offsets`` (version 1)."""
    data = _load_npz(path, ("ids", "weights"), either=("counts", "offsets"))
    if "counts" in data:
        offsets = np.zeros(data["counts"].shape[0] + 1, dtype=np.int64)
        np.cumsum(data["counts"], out=offsets[1:])
    else:
        offsets = data["offsets"].astype(np.int64, copy=False)
    if offsets.shape[0] != width * height + 1 or offsets[-1] != data["ids"].shape[0]:
        raise InputError.single(str(path), f"the weights do not fit a {width}x{height} view")
    return BlendWeights(
        height=height,
        width=width,
        offsets=torch.from_numpy(offsets),
        ids=torch.from_numpy(data["ids"]),
        weights=torch.from_numpy(data["weights"].astype(np.float32, copy=False)),
    )


def _load_npz(
    path: Path, keys: Sequence[str], either: Sequence[str] = ()
) -> dict[str, NDArray[Any]]:
    """The arrays ``keys`` (and the first of ``either`` present) of ``path``: read straight
    from the file (:func:`dcseg.io.npz.read_stored`), by :func:`numpy.load` when compressed."""
    try:
        arrays = read_stored(path, [*keys, *either])
        if arrays is None:
            with np.load(path, allow_pickle=False) as data:
                arrays = {k: np.asarray(data[k]) for k in [*keys, *either] if k in data.files}
    except (OSError, ValueError) as error:
        raise InputError.single(str(path), f"cannot read saved state: {error}") from None
    for k in [k for k in either if k in arrays][1:]:
        del arrays[k]
    missing = [k for k in keys if k not in arrays]
    if either and not any(k in arrays for k in either):
        missing.append(" or ".join(either))
    if missing:
        raise InputError.single(str(path), f"missing arrays: {', '.join(missing)}")
    return arrays
