"""The ``run.json`` record of a trained or segmented run."""

from __future__ import annotations

import platform
from importlib import metadata
from typing import TYPE_CHECKING, Any

from dcseg import __version__
from dcseg.stages.base import Clock, peak_mb

if TYPE_CHECKING:
    from dcseg.config import PipelineConfig
    from dcseg.io.run_output import SavedRun
    from dcseg.segmentation import Segmentation


def base_record(saved: SavedRun, cfg: PipelineConfig, clock: Clock) -> dict[str, Any]:
    """What every ``run.json`` holds: the run's record, the resolved config, seconds and peak
    memory per phase, backend, library versions and the cache's size."""
    from dcseg.render import select_backend

    return {
        **saved.record,
        "dcseg_version": __version__,
        "config": cfg.to_dict(),
        "seed": cfg.seed,
        "seconds": clock.seconds,
        "peak_memory_mb": peak_mb(),
        "peak_memory_mb_by_phase": clock.peak_mb,
        "backend": select_backend(saved.trained.gaussians.device, cfg.reconstruct.backend),
        "versions": versions(),
        "cache_mb": round(sum(v.cache_bytes() for v in saved.trained.views) / 2**20, 1),
    }


def segmented_record(
    saved: SavedRun,
    cfg: PipelineConfig,
    segmentation: Segmentation,
    clock: Clock,
    metrics: dict[str, Any] | None,
) -> dict[str, Any]:
    """:func:`base_record` with the segmentation's counts and the metrics' summary."""
    a = segmentation.assignment
    return {
        **base_record(saved, cfg, clock),
        "counts": {
            "gaussians": len(saved.trained.gaussians),
            "views": len(saved.trained.views),
            "clusters": segmentation.n_clusters,
            "labelled_clusters": int((a.labels >= 0).sum()),
            "instances": segmentation.n_instances,
            "labelled_gaussians": int((segmentation.semantic_ids >= 0).sum()),
        },
        "segmentation": {
            "mask_agreement": round(segmentation.mask_agreement, 4),  # write_json: NaN -> null
            "evidence_trusted": segmentation.evidence_trusted,
            "unanimous_clusters": round(segmentation.unanimous, 4),  # NaN -> null
            "confusions_undone": segmentation.confusions,
            "ring_gaussians_given_back": segmentation.rings_given_back,
            "background_gaussians": segmentation.background,
        },
        "metrics_summary": None if metrics is None else metrics["summary"],
    }


def versions() -> dict[str, str]:
    """The versions of Python and of the libraries results depend on."""
    found = {"python": platform.python_version()}
    for package in ("torch", "numpy", "numba", "hdbscan", "scipy"):
        try:
            found[package] = metadata.version(package)
        except metadata.PackageNotFoundError:  # pragma: no cover
            found[package] = "missing"
    return found
