"""Compile (or load from numba's on-disk cache) every numba kernel before the first real run.

Each kernel is compiled on first use, ~30 s of CPU in all when nothing is cached. Every kernel
is declared ``cache=True``, so a compiled kernel is written next to its module
(``__pycache__``) or, when ``NUMBA_CACHE_DIR`` is set, under that folder (set it where the
package folder is read-only, e.g. an installed image). :func:`warm_kernels` runs the stages
that call the kernels on a tiny scene built in memory (a few Gaussians, 64x48 views), so the
kernels are compiled for the argument types a real run passes, and reports each kernel.

A real run may still compile a kernel for argument types the tiny scene does not produce (for
example non-contiguous blocks of a large pairwise table); it is cached then, once.
"""

from __future__ import annotations

import importlib
import math
import tempfile
from dataclasses import dataclass, replace
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

KERNEL_MODULES = (
    "dcseg.affinity.kernels",
    "dcseg.blend_kernels",
    "dcseg.cluster.components",
    "dcseg.export.tsdf",
    "dcseg.reconstruct.depth_filter",
    "dcseg.reconstruct.depth_noise",
    "dcseg.reconstruct.flying",
    "dcseg.reconstruct.surface",
    "dcseg.render.cpu_planar",
    "dcseg.render.blend_weights",
    "dcseg.render.numba_kernels",
    "dcseg.render.numba_projection",
)
"""Every module that defines numba kernels (a test keeps this list complete)."""

_SIZE = (64, 48)
_FRAMES = 4


@dataclass(frozen=True)
class Kernel:
    """What warming did to one numba kernel.

    Attributes:
        name: ``module.function``.
        signatures: the argument types it is now compiled for.
        status: ``compiled`` (and written to the cache), ``loaded`` (from the cache),
            ``in memory`` (compiled earlier in this process), ``in callers`` (a helper only
            called from other kernels: its code is part of theirs) or ``missed`` (an entry
            kernel the tiny scene did not reach).
        cache: the kernel's cache folder.
    """

    name: str
    signatures: int
    status: str
    cache: str


def kernel_dispatchers() -> dict[str, Any]:
    """``{"module.function": dispatcher}`` of the kernels defined in :data:`KERNEL_MODULES`."""
    from numba.core.dispatcher import Dispatcher

    found = {}
    for name in KERNEL_MODULES:
        module = importlib.import_module(name)
        for attr, value in sorted(vars(module).items()):
            if isinstance(value, Dispatcher) and value.py_func.__module__ == name:
                found[f"{name}.{attr}"] = value
    return found


def helpers(dispatchers: dict[str, Any]) -> set[str]:
    """The kernels called from another kernel of their module (compiled into the callers)."""
    out = set()
    for name in dispatchers:
        module, attr = name.rsplit(".", 1)
        for other, caller in dispatchers.items():
            if other != name and other.startswith(module + ".") and attr in _names(caller):
                out.add(name)
    return out


def _names(dispatcher: Any) -> set[str]:
    code = dispatcher.py_func.__code__
    return set(code.co_names)


def warm_kernels(workdir: Path | None = None) -> list[Kernel]:
    """Run every kernel-using stage on a tiny scene; report each kernel (sorted by name).

    Args:
        workdir: where the tiny run's blending-weight cache is written; None = a temporary
            folder, removed afterwards.
    """
    if workdir is None:
        with tempfile.TemporaryDirectory(prefix="dcseg-warmup-") as tmp:
            return warm_kernels(Path(tmp))
    _run_tiny_scene(workdir)
    return report()


def report() -> list[Kernel]:
    """Each kernel's state in this process (see :class:`Kernel`)."""
    dispatchers = kernel_dispatchers()
    inner = helpers(dispatchers)
    out = []
    for name, disp in dispatchers.items():
        stats = disp.stats
        hits, misses = sum(stats.cache_hits.values()), sum(stats.cache_misses.values())
        n = len(disp.signatures)
        if n == 0:
            status = "in callers" if name in inner else "missed"
        elif misses:
            status = "compiled"
        elif hits:
            status = "loaded"
        else:
            status = "in memory"
        out.append(Kernel(name, n, status, str(stats.cache_path)))
    return out


def _run_tiny_scene(workdir: Path) -> None:
    """Reconstruct, cache, train affinity, segment and fuse depth on :func:`tiny_capture`."""
    # the stages' own entry points, so that the kernels see the argument types of a real run
    from dcseg.config import preset
    from dcseg.export.depth import DepthView
    from dcseg.export.tsdf import fuse
    from dcseg.pipeline import segment_scene, train_scene
    from dcseg.reconstruct import fit_gaussians
    from dcseg.reconstruct.config import SURFACE_PRIORS
    from dcseg.reconstruct.depth_filter import window_median
    from dcseg.segment import class_agreement

    capture, agnostic, semantic = tiny_capture()
    cfg = preset("fast")
    priors: dict[str, Any] = dict(SURFACE_PRIORS)
    cfg = replace(
        cfg,
        # with --surface-priors: their kernels too (the others run either way)
        reconstruct=replace(cfg.reconstruct, iterations=3, holdout=2, backend="cpu", **priors),
        affinity=replace(cfg.affinity, iterations=3, rays=128),
        cache=replace(cfg.cache, memory_mb=1),
    )
    reconstruction = fit_gaussians(capture, cfg.reconstruct, device="cpu")
    trained = train_scene(reconstruction.gaussians, capture, agnostic, cfg, cache_dir=workdir)
    segmented = segment_scene(trained, semantic, 3, cfg, class_names=("left", "right", "wall"))
    blends = [view.blend for view in trained.views]  # not used by the pipeline, a public API
    class_agreement(
        blends, [semantic[v.name].classes for v in trained.views], segmented.semantic_ids
    )
    views = [
        DepthView(f.name, f.intrinsics.matrix(), f.c2w, partial(np.array, f.depth))
        for f in capture.frames
    ]
    fuse(views, per_side=16)
    # the depth filter's median runs only on noisy depth, which the tiny scene has not
    window_median(np.ascontiguousarray(capture.frames[0].depth, dtype=np.float32), 2, 1, 0)


def tiny_capture() -> tuple[Any, dict[str, Any], dict[str, Any]]:
    """``(capture, agnostic masks, class maps)`` of two boxes in front of a wall, 4 views.

    The wall is the plane z = 2 (class 2); two fronto-parallel panels at z = 1.4 (classes 0 and
    1) stand in front of it. Cameras look along +z from slightly different positions.
    """
    from dcseg.io.masks import _encode
    from dcseg.types import AgnosticMasks, Capture, Frame, Intrinsics, SemanticMap

    width, height = _SIZE
    k = Intrinsics(fx=60.0, fy=60.0, cx=width / 2 - 0.5, cy=height / 2 - 0.5, width=width,
                   height=height)  # fmt: skip
    frames, agnostic, semantic = [], {}, {}
    for i in range(_FRAMES):
        angle = 2 * math.pi * i / _FRAMES
        c2w = np.eye(4)
        c2w[:3, 3] = [0.1 * math.cos(angle), 0.1 * math.sin(angle), 0.0]
        classes, depth = _render_panels(c2w[:3, 3], k)
        rgb = np.array([[200, 60, 60], [60, 200, 60], [90, 90, 220]], np.uint8)[classes]
        rgb = rgb + (np.indices(classes.shape).sum(axis=0) % 7 * 4).astype(np.uint8)[..., None]
        name = f"frame{i:03d}"
        frames.append(Frame(name=name, rgb=rgb, depth=depth, intrinsics=k, c2w=c2w))
        masks = [classes == 0, classes == 1, classes == 2, classes < 2]
        agnostic[name] = AgnosticMasks(name, height, width, tuple(_encode(m) for m in masks))
        semantic[name] = SemanticMap(name, classes.astype(np.int32))
    return Capture(frames=tuple(frames), layout="dcseg"), agnostic, semantic


def _render_panels(
    position: NDArray[np.float64], k: Any
) -> tuple[NDArray[np.int64], NDArray[np.float32]]:
    """Class and depth per pixel seen from ``position`` (identity rotation)."""
    v, u = np.indices((k.height, k.width), dtype=np.float64)
    rx, ry = (u - k.cx) / k.fx, (v - k.cy) / k.fy  # ray direction per unit z
    classes = np.full((k.height, k.width), 2, np.int64)
    depth = np.full((k.height, k.width), 2.0 - position[2], np.float32)
    z = 1.4 - position[2]
    x, y = position[0] + rx * z, position[1] + ry * z
    for cls, (x0, x1) in enumerate([(-0.5, -0.08), (0.08, 0.5)]):
        hit = (x >= x0) & (x < x1) & (np.abs(y) < 0.3)
        classes[hit] = cls
        depth[hit] = z
    return classes, depth
