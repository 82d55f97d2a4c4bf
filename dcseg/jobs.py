"""Whole jobs over files: run, re-cluster, re-classify, evaluate (used by the CLI and workers).

Each job reads its inputs, calls the pipeline, and publishes a complete output folder
(:mod:`dcseg.io.run_output`). Nothing here prints; progress goes through ``on_progress``.
"""

from __future__ import annotations

import logging
import os
import platform
import resource
import shutil
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from importlib import metadata
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from dcseg import __version__
from dcseg.config import CaptureOptions, PipelineConfig
from dcseg.errors import InputError
from dcseg.gaussians import Gaussians
from dcseg.io.bundle import BUNDLE_LAYOUT, bundle_paths
from dcseg.io.captures import read_planned
from dcseg.io.captures.plan import CapturePlan
from dcseg.io.folders import FrameSelection
from dcseg.io.ground_truth import read_ground_truth
from dcseg.io.jsonfile import write_json
from dcseg.io.masks import read_agnostic_masks
from dcseg.io.ply import read_gaussians_ply
from dcseg.io.poses import POSES_FILE, read_poses
from dcseg.io.run_output import (
    SavedRun,
    load_labels,
    load_run,
    preview_indices,
    publish,
    save_clusters,
    save_semantic,
    save_state,
    staging_dir,
    write_outputs,
)
from dcseg.io.semantic import read_semantic_maps, read_vocabulary
from dcseg.pipeline import (
    Labels,
    Progress,
    Segmentation,
    evaluate_segmentation,
    segment_scene,
    train_scene,
)
from dcseg.render import select_backend
from dcseg.sizes import SceneSize, describe, resolve
from dcseg.types import Capture, GroundTruth, Vocabulary

if TYPE_CHECKING:
    import torch

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RunInputs:
    """The files of one segmentation job."""

    capture: Path
    agnostic_masks: Path
    semantic_masks: Path
    vocabulary: Path
    ground_truth: Path | None = None
    scene: Path | None = None
    capture_options: CaptureOptions = field(default_factory=CaptureOptions)

    @classmethod
    def from_bundle(
        cls,
        root: Path,
        *,
        scene: Path | None = None,
        capture_options: CaptureOptions | None = None,
    ) -> RunInputs:
        """The inputs of a bundle folder (:mod:`dcseg.io.bundle`); InputError names what is
        missing (masks and vocabulary are required, ground truth is optional)."""
        found = bundle_paths(root)
        required = ("agnostic_masks", "semantic_masks", "vocabulary")
        missing = [name for name in required if found[name] is None]
        if missing:
            where = ", ".join(f"{n} ({' or '.join(BUNDLE_LAYOUT[n])})" for n in missing)
            raise InputError.single(str(root), f"the bundle has no {where}")
        return cls(
            capture=root,
            agnostic_masks=_present(found["agnostic_masks"]),
            semantic_masks=_present(found["semantic_masks"]),
            vocabulary=_present(found["vocabulary"]),
            ground_truth=found["ground_truth"],
            scene=scene,
            capture_options=capture_options or CaptureOptions(),
        )


def _present(path: Path | None) -> Path:
    if path is None:  # pragma: no cover - checked by the caller
        raise ValueError("missing bundle input")
    return path


class _Clock:
    """Seconds per named phase, and the process's peak memory by the end of each phase."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}
        self.peak_mb: dict[str, float] = {}

    @contextmanager
    def phase(self, name: str) -> Iterator[None]:
        start = time.perf_counter()
        yield
        self.seconds[name] = round(self.seconds.get(name, 0.0) + time.perf_counter() - start, 3)
        self.peak_mb[name] = _peak_mb()


def _peak_mb() -> float:
    """The process's peak resident memory so far (MB)."""
    return round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)


def _quiet(stage: str, fraction: float, message: str) -> None:
    return None


def run_job(
    inputs: RunInputs,
    cfg: PipelineConfig,
    out: Path,
    on_progress: Progress = _quiet,
    *,
    device: str = "auto",
) -> dict[str, Any]:
    """Reconstruct (unless a scene is given), train, segment, evaluate and publish ``out``.

    ``device`` (:func:`dcseg.devices.resolve_device`) is where reconstruction, the cache's
    projection and affinity training run; clustering and classification run on the host.

    Returns:
        The ``run.json`` record.
    """
    clock = _Clock()
    with clock.phase("read"):
        capture, plan = read_planned(inputs.capture, inputs.capture_options, cfg.budget)
        vocabulary = read_vocabulary(inputs.vocabulary)
        semantic = read_semantic_maps(
            inputs.semantic_masks, vocabulary, size=_frame_size(capture), frames=_selection(plan)
        )
        gt = _read_gt(inputs.ground_truth, vocabulary)
    tmp = staging_dir(out)
    try:
        trained, cfg = _train(inputs, capture, plan, cfg, clock, on_progress, device, tmp / "state")
        del capture  # the views' depth and weights are in state/ now; previews keep a few frames
        saved = replace(trained, semantic=dict(semantic), vocabulary=vocabulary)
        return _finish(saved, cfg, out, clock, gt, on_progress, train_state=True, tmp=tmp)
    except BaseException:
        _discard(tmp)
        raise


def train_job(
    inputs: RunInputs,
    cfg: PipelineConfig,
    out: Path,
    on_progress: Progress = _quiet,
    *,
    device: str = "auto",
) -> dict[str, Any]:
    """Reconstruct (unless a scene is given) and train features only.

    ``out`` gets ``state/`` and ``run.json``, from which :func:`resegment_job` clusters and
    classifies as often as wanted (the service's derived jobs rely on this split).
    """
    clock = _Clock()
    with clock.phase("read"):
        capture, plan = read_planned(inputs.capture, inputs.capture_options, cfg.budget)
    tmp = staging_dir(out)
    try:
        saved, cfg = _train(inputs, capture, plan, cfg, clock, on_progress, device, tmp / "state")
        save_state(tmp, saved.trained, {}, None, saved.previews)
        record = _base_record(saved, cfg, clock)
        write_json(tmp / "run.json", record)
        publish(tmp, out)
    except BaseException:
        _discard(tmp)
        raise
    return record


def _train(
    inputs: RunInputs,
    capture: Capture,
    plan: CapturePlan,
    cfg: PipelineConfig,
    clock: _Clock,
    on_progress: Progress,
    device: str,
    state: Path,
) -> tuple[SavedRun, PipelineConfig]:
    """Read the class-agnostic masks, reconstruct and train: a run without class masks yet.

    The size rules (:mod:`dcseg.sizes`) are applied as the sizes become known: views and pixels
    before reconstruction, Gaussians after it. Returns the run and the resolved config (which
    ``run.json`` stores, so re-segmenting runs with the same values); the record's
    ``size_rules`` lists each resolved value. The blend-weight cache is written into ``state``
    (the staged run's ``state/``) view by view, so it is never held in memory as a whole."""
    from dcseg.reconstruct.job import device_of

    where = device_of(device)
    with clock.phase("read"):
        agnostic = read_agnostic_masks(
            inputs.agnostic_masks, size=_frame_size(capture), frames=_selection(plan)
        )
    if not any(len(m) for m in agnostic.values()):
        raise InputError.single("class-agnostic masks", "no frame has any mask")
    reconstruction: dict[str, Any] = {"device": str(where)}
    width, height = _frame_size(capture)
    size = SceneSize(views=len(capture), pixels=width * height)
    given, cfg = cfg, resolve(cfg, size)
    with clock.phase("reconstruct"):
        gaussians, capture = _scene(inputs, capture, cfg, on_progress, reconstruction, where)
    size = replace(size, gaussians=len(gaussians))
    cfg = resolve(cfg, size)
    with clock.phase("train"):
        trained = train_scene(gaussians, capture, agnostic, cfg, on_progress, cache_dir=state)
    picked = [capture.frames[i] for i in preview_indices(len(capture))]
    previews = [(f.name, f.rgb) for f in picked]
    record = {
        "inputs": _describe(inputs),
        "capture": plan.summary(),
        "reconstruction": reconstruction,
        "size_rules": describe(given, cfg, size),
    }
    return SavedRun(trained, {}, Vocabulary(()), previews, record), cfg


def resegment_job(
    run: Path,
    out: Path,
    *,
    scale: float | None = None,
    matcher: str | None = None,
    label_maps: str | None = None,
    semantic_masks: Path | None = None,
    vocabulary: Path | None = None,
    ground_truth: Path | None = None,
    on_progress: Progress = _quiet,
) -> dict[str, Any]:
    """Cluster and classify a trained run again; nothing is trained.

    Args:
        run: a run folder (from :func:`run_job`, :func:`train_job` or this function).
        out: the new output folder (not ``run``).
        scale: a new clustering scale (``recluster``); None keeps the run's.
        matcher: ``"assignment"`` or ``"matching"``; None keeps the run's.
        label_maps: what ``labels/`` shows, ``"gaussians"`` or ``"clusters"``
            (``AssignConfig.maps_from``); None keeps the run's.
        semantic_masks, vocabulary: new class-aware masks (``reclassify``); None keeps the
            run's. A run from :func:`train_job` has none, so they are required there.
        ground_truth: a ground-truth PLY to evaluate against.
        on_progress: progress callback.
    """
    _check_distinct(run, out)
    clock = _Clock()
    with clock.phase("read"):
        saved = load_run(run)
        if semantic_masks is not None or vocabulary is not None:
            saved = _with_semantic(saved, semantic_masks, vocabulary)
        if not saved.semantic:
            reason = "the run holds no class-aware masks; give new ones and a vocabulary"
            raise InputError.single(str(run), reason)
        gt = _read_gt(ground_truth, saved.vocabulary)
    cfg = _config(saved, run)
    cfg = replace(cfg, scale=cfg.scale if scale is None else scale)
    if matcher is not None:
        cfg = replace(cfg, assign=replace(cfg.assign, mode=matcher))  # type: ignore[arg-type]
    if label_maps is not None:
        cfg = replace(cfg, assign=replace(cfg.assign, maps_from=label_maps))  # type: ignore[arg-type]
    record = {**saved.record, "parent": str(run)}
    return _finish(replace(saved, record=record), cfg, out, clock, gt, on_progress)


def _with_semantic(saved: SavedRun, masks: Path | None, vocabulary_file: Path | None) -> SavedRun:
    if masks is None or vocabulary_file is None:
        raise InputError.single("semantic masks", "new class-aware masks need a vocabulary")
    vocabulary = read_vocabulary(vocabulary_file)
    names = frozenset(v.name for v in saved.trained.views)
    listed = saved.record.get("capture", {}).get("listed_frames")
    frames = FrameSelection(names, names if listed is None else frozenset(listed))
    semantic = read_semantic_maps(masks, vocabulary, size=_view_size(saved), frames=frames)
    return replace(saved, semantic=semantic, vocabulary=vocabulary)


def evaluate_job(run: Path, gt_file: Path) -> dict[str, Any]:
    """Evaluate a finished run against ground truth; writes and returns ``metrics.json``."""
    saved = load_run(run)
    gt = read_ground_truth(gt_file, len(saved.vocabulary))
    labels = load_labels(run, [v.name for v in saved.trained.views], size=_view_size(saved))
    return _evaluate(saved, labels, gt, _config(saved, run), run)


def _finish(
    saved: SavedRun,
    cfg: PipelineConfig,
    out: Path,
    clock: _Clock,
    gt: GroundTruth | None,
    on_progress: Progress,
    train_state: bool = False,
    tmp: Path | None = None,
) -> dict[str, Any]:
    trained, vocabulary = saved.trained, saved.vocabulary
    tmp = staging_dir(out) if tmp is None else tmp
    try:
        with clock.phase("segment"):
            segmentation = segment_scene(
                trained, saved.semantic, len(vocabulary), cfg, on_progress, vocabulary.names
            )
        with clock.phase("evaluate"):
            metrics = None if gt is None else _evaluate(saved, segmentation.labels(), gt, cfg, tmp)
        with clock.phase("write"):
            write_outputs(
                tmp, trained, segmentation, vocabulary, saved.previews, size=_output_size(saved)
            )
            _write_state(tmp, saved, train_state)
            save_clusters(tmp / "state", segmentation)
        record = _record(saved, cfg, segmentation, clock, metrics)
        write_json(tmp / "run.json", record)
        publish(tmp, out)
    except BaseException:
        _discard(tmp)
        raise
    on_progress("done", 1.0, f"wrote {out}")
    return record


def _write_state(tmp: Path, saved: SavedRun, full: bool) -> None:
    """Fresh runs save everything; derived runs copy the parent's trained state."""
    if full:
        save_state(tmp, saved.trained, saved.semantic, saved.vocabulary, saved.previews)
        return
    parent = Path(str(saved.record["parent"])) / "state"
    _copy_tree(parent, tmp / "state", skip=("semantic", "vocabulary.json", "clusters.npz"))
    save_semantic(tmp / "state", saved.semantic, saved.vocabulary)


def _evaluate(
    saved: SavedRun, labels: Labels, gt: GroundTruth, cfg: PipelineConfig, folder: Path
) -> dict[str, Any]:
    """Evaluate labels against ground truth and write ``folder/metrics.json``."""
    metrics = evaluate_segmentation(
        saved.trained, labels, saved.semantic, gt, saved.vocabulary, cfg
    )
    write_json(folder / "metrics.json", metrics)
    return metrics


def _base_record(saved: SavedRun, cfg: PipelineConfig, clock: _Clock) -> dict[str, Any]:
    return {
        **saved.record,
        "dcseg_version": __version__,
        "config": cfg.to_dict(),
        "seed": cfg.seed,
        "seconds": clock.seconds,
        "peak_memory_mb": _peak_mb(),
        "peak_memory_mb_by_phase": clock.peak_mb,
        "backend": select_backend(saved.trained.gaussians.device, cfg.reconstruct.backend),
        "versions": _versions(),
        "cache_mb": round(sum(v.cache_bytes() for v in saved.trained.views) / 2**20, 1),
    }


def _record(
    saved: SavedRun,
    cfg: PipelineConfig,
    segmentation: Segmentation,
    clock: _Clock,
    metrics: dict[str, Any] | None,
) -> dict[str, Any]:
    a = segmentation.assignment
    return {
        **_base_record(saved, cfg, clock),
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
        },
        "metrics_summary": None if metrics is None else metrics["summary"],
    }


def _versions() -> dict[str, str]:
    versions = {"python": platform.python_version()}
    for package in ("torch", "numpy", "numba", "hdbscan", "scipy"):
        try:
            versions[package] = metadata.version(package)
        except metadata.PackageNotFoundError:  # pragma: no cover
            versions[package] = "missing"
    return versions


def _scene(
    inputs: RunInputs,
    capture: Capture,
    cfg: PipelineConfig,
    on_progress: Progress,
    summary: dict[str, Any],
    device: torch.device,
) -> tuple[Gaussians, Capture]:
    """The Gaussians (given or reconstructed) and the capture at the poses they fit: the
    refined poses when reconstruction refines them (``ReconstructConfig.pose_lr``), or when a
    given scene has them in the ``poses.json`` beside it (what ``dcseg reconstruct
    --refine-poses`` and the worker's reconstruct stage write)."""
    from dcseg.reconstruct.poses import with_poses

    if inputs.scene is not None:
        summary["scene"] = str(inputs.scene)
        refined = _refined_poses_beside(inputs.scene)
        if refined is not None:
            capture = with_poses(capture, _covering(refined, capture, inputs.scene))
            summary["pose_refinement"] = {"poses_from": str(inputs.scene.parent)}
        return read_gaussians_ply(inputs.scene).to(device), capture
    from dcseg.reconstruct.job import reconstruct_scene

    def report(step: int, total: int, loss: float) -> None:
        on_progress("reconstruct", step / total, f"step {step}/{total} loss {loss:.4f}")

    gaussians, record = reconstruct_scene(capture, cfg.reconstruct, device, report)
    summary.update({k: v for k, v in record.items() if k not in ("views", "config")})
    refinement = record.get("pose_refinement")
    if refinement is not None:
        capture = with_poses(capture, refinement["poses"])
        summary["pose_refinement"] = {k: v for k, v in refinement.items() if k != "poses"}
    return gaussians, capture


def _refined_poses_beside(scene: Path) -> dict[str, NDArray[np.float64]] | None:
    """The refined poses in the ``poses.json`` next to ``scene``, if there is one."""
    path = scene.parent / POSES_FILE
    return read_poses(path) if path.is_file() else None


def _covering(
    poses: dict[str, NDArray[np.float64]], capture: Capture, scene: Path
) -> dict[str, NDArray[np.float64]]:
    """``poses`` when they cover every frame of ``capture``; an InputError otherwise (a scene
    fitted to refined poses cannot be used with the capture's own poses for some frames)."""
    missing = [f.name for f in capture.frames if f.name not in poses]
    if missing:
        reason = (
            f"has refined poses for the scene but none for {len(missing)} of the capture's "
            f"frames (first: {missing[0]}); reconstruct with the same frames and budget"
        )
        raise InputError.single(str(scene.parent / POSES_FILE), reason)
    return poses


def _config(saved: SavedRun, run: Path) -> PipelineConfig:
    """The run's stored config; retired fields are dropped with a warning."""
    try:
        cfg, dropped = PipelineConfig.from_stored(saved.record["config"])
    except (KeyError, TypeError, ValueError) as exc:
        reason = f"config cannot be read by this dcseg version: {exc}"
        raise InputError.single(str(run / "run.json"), reason) from exc
    if dropped:
        log.warning("%s: ignoring retired config fields %s", run, ", ".join(dropped))
    return cfg


def _frame_size(capture: Capture) -> tuple[int, int]:
    sizes = {(f.width, f.height) for f in capture.frames}
    if len(sizes) != 1:
        shown = ", ".join(f"{w}x{h}" for w, h in sorted(sizes))
        raise InputError.single(
            capture.root or "capture", f"frames differ in size ({shown}); give --size WxH"
        )
    return sizes.pop()


def _read_gt(path: Path | None, vocabulary: Vocabulary) -> GroundTruth | None:
    return None if path is None else read_ground_truth(path, len(vocabulary))


def _selection(plan: CapturePlan) -> FrameSelection:
    """Masks are read for the planned frames only; masks of frames the capture lacks are
    refused, those of frames the plan left out are skipped unread."""
    return FrameSelection(frozenset(plan.names), frozenset(plan.listed))


def _view_size(saved: SavedRun) -> tuple[int, int]:
    """The working ``(width, height)`` of a trained run's views."""
    return saved.trained.views[0].width, saved.trained.views[0].height


def _output_size(saved: SavedRun) -> tuple[int, int] | None:
    """The capture's resolution, at which per-view outputs are written (None = the views')."""
    size = saved.record.get("capture", {}).get("output_size")
    return None if size is None else (int(size[0]), int(size[1]))


def _describe(inputs: RunInputs) -> dict[str, Any]:
    return {
        "capture": str(inputs.capture),
        "agnostic_masks": str(inputs.agnostic_masks),
        "semantic_masks": str(inputs.semantic_masks),
        "vocabulary": str(inputs.vocabulary),
        "ground_truth": None if inputs.ground_truth is None else str(inputs.ground_truth),
        "scene": None if inputs.scene is None else str(inputs.scene),
    }


def _check_distinct(run: Path, out: Path) -> None:
    if out.resolve() == run.resolve():
        raise InputError.single(str(out), "the new output must not replace the run it derives from")


def _copy_tree(src: Path, dst: Path, skip: tuple[str, ...]) -> None:
    """Copy a parent's state (hard links where possible: state files are never modified)."""
    shutil.copytree(
        src, dst, ignore=lambda folder, names: [n for n in names if n in skip], copy_function=_link
    )


def _link(src: str, dst: str) -> None:
    try:
        os.link(src, dst)
    except OSError:
        shutil.copy2(src, dst)


def _discard(tmp: Path) -> None:
    shutil.rmtree(tmp, ignore_errors=True)
