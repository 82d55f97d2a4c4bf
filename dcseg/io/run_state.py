"""A run's trained state on disk, so later runs re-cluster or re-classify without training.

Layout under ``RUN/state/``::

    gaussians.ply        the frozen Gaussians (3DGS PLY layout)
    affinity.npz         features [N,D], gate_weight [D,1], gate_bias [D], scale_quantiles [Q],
                         losses [T]
    views.json           per view: name, width, height, K (3x3), c2w (4x4)
    views/<i>.npz        per view: blend weights (offsets, ids, weights) and depth (float16 m)
    semantic/            the class-aware maps the run used (for re-clustering)
    vocabulary.json      their vocabulary

Arrays are written with :func:`numpy.savez` (uncompressed: it is a cache read back whole).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray

from dcseg.affinity.data import AffinityResult
from dcseg.blend import BlendWeights
from dcseg.errors import InputError

STATE_VERSION = 1


@dataclass(frozen=True)
class ViewState:
    """One view as the segmentation stages need it after training.

    Attributes:
        name: the frame stem.
        K: ``[3, 3]`` intrinsics.
        c2w: ``[4, 4]`` camera-to-world pose.
        blend: the frozen Gaussians' blending weights in this view.
        depth: ``[H, W]`` float32 capture depth (metres, 0 = invalid), for evaluation.
    """

    name: str
    K: NDArray[np.float64]
    c2w: NDArray[np.float64]
    blend: BlendWeights
    depth: NDArray[np.float32]


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
    """Write ``views.json`` and one ``views/<i>.npz`` per view."""
    (folder / "views").mkdir(parents=True, exist_ok=True)
    meta = []
    for i, view in enumerate(views):
        b = view.blend
        np.savez(
            folder / "views" / f"{i}.npz",
            offsets=b.offsets.cpu().numpy(),
            ids=b.ids.cpu().numpy(),
            weights=b.weights.cpu().numpy(),
            depth=view.depth.astype(np.float16),
        )
        meta.append(
            {
                "name": view.name,
                "width": b.width,
                "height": b.height,
                "K": view.K.tolist(),
                "c2w": view.c2w.tolist(),
            }
        )
    body = {"version": STATE_VERSION, "views": meta}
    (folder / "views.json").write_text(json.dumps(body) + "\n", encoding="utf-8")


def load_views(folder: Path) -> list[ViewState]:
    """Read what :func:`save_views` wrote."""
    path = folder / "views.json"
    try:
        body = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as error:
        raise InputError.single(str(path), f"cannot read the run's views: {error}") from None
    if body.get("version") != STATE_VERSION:
        raise InputError.single(str(path), f"unsupported state version {body.get('version')}")
    return [_load_view(folder, i, meta) for i, meta in enumerate(body["views"])]


def _load_view(folder: Path, index: int, meta: dict[str, Any]) -> ViewState:
    data = _load_npz(folder / "views" / f"{index}.npz", ("offsets", "ids", "weights", "depth"))
    blend = BlendWeights(
        height=int(meta["height"]),
        width=int(meta["width"]),
        offsets=torch.from_numpy(data["offsets"]),
        ids=torch.from_numpy(data["ids"]),
        weights=torch.from_numpy(data["weights"]),
    )
    return ViewState(
        name=str(meta["name"]),
        K=np.asarray(meta["K"], dtype=np.float64),
        c2w=np.asarray(meta["c2w"], dtype=np.float64),
        blend=blend,
        depth=data["depth"].astype(np.float32),
    )


def _load_npz(path: Path, keys: Sequence[str]) -> dict[str, NDArray[Any]]:
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: np.asarray(data[k]) for k in keys if k in data.files}
    except (OSError, ValueError) as error:
        raise InputError.single(str(path), f"cannot read saved state: {error}") from None
    missing = [k for k in keys if k not in arrays]
    if missing:
        raise InputError.single(str(path), f"missing arrays: {', '.join(missing)}")
    return arrays
