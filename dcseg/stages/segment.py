"""The segment stage (method steps 3-6) on a trained run: clusters, classes, objects, exports.

Without class-aware masks (none given and none in the run) it is class-agnostic: clusters
become objects without classes, and evaluation reports the instance metrics only.

Reads the train stage's ``state/`` (handed over in memory when both ran in one process) and
the class-aware masks, and writes the run folder users download (:mod:`dcseg.io.run_output`):
labelled Gaussians, instances, per-view maps, preview, metrics with ground truth, ``run.json``
and ``state/`` (the trained state, linked, plus the class masks and clusters), so the result
can be re-clustered and re-classified again without training.
"""

from __future__ import annotations

import shutil
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from dcseg.errors import InputError
from dcseg.io.folders import link_or_copy
from dcseg.io.jsonfile import write_json
from dcseg.sizes import SceneSize, resolve
from dcseg.stages.base import Stage, StageResult, StageRun
from dcseg.stages.records import segmented_record
from dcseg.stages.train import RUN_RECORD

if TYPE_CHECKING:
    from dcseg.config import PipelineConfig
    from dcseg.io.run_output import SavedRun
    from dcseg.segmentation import Labels
    from dcseg.types import GroundTruth

FROM_TRAIN_SKIPPED = ("semantic", "vocabulary.json", "clusters.npz")
"""Files of a trained ``state/`` that a new segmentation writes itself."""


def segment(run: StageRun) -> StageResult:
    """Cluster, classify, evaluate and write the run folder."""
    from dcseg.io.run_output import save_clusters, save_semantic, write_outputs
    from dcseg.lens import of_record
    from dcseg.pipeline import segment_scene

    saved = _trained(run)
    if saved is None:
        return StageResult("skipped", "segment: nothing was trained (no masks uploaded)")
    with run.clock.phase("read"):
        saved = _with_semantic(run, saved)
        gt = _ground_truth(run, saved)
    cfg = resolve(run.config.pipeline, size_of(saved))
    trained, vocabulary = saved.trained, saved.vocabulary
    with run.clock.phase("segment"):
        segmentation = segment_scene(
            trained, saved.semantic, len(vocabulary), cfg, run.progress, vocabulary.names
        )
    with run.clock.phase("evaluate"):
        metrics = None if gt is None else evaluate(saved, segmentation.labels(), gt, cfg, run.out)
    with run.clock.phase("write"):
        size = _output_size(saved)
        lenses = of_record(saved.record)  # maps go back onto distorted images
        write_outputs(
            run.out,
            trained,
            segmentation,
            vocabulary,
            saved.previews,
            size=size,
            undistorted=lenses,
        )
        link_tree(run.folder("train") / "state", run.out / "state", skip=FROM_TRAIN_SKIPPED)
        if len(vocabulary):  # a class-agnostic run's state holds no class masks
            save_semantic(run.out / "state", saved.semantic, vocabulary)
        save_clusters(run.out / "state", segmentation)
    record = segmented_record(saved, cfg, segmentation, run.clock, metrics)
    write_json(run.out / RUN_RECORD, record)
    counts = record["counts"]
    message = f"segment: {counts['clusters']} instances, {counts['labelled_clusters']} labelled"
    if not len(vocabulary):
        message = f"segment: {counts['instances']} objects, class-agnostic (no class-aware masks)"
    return StageResult("done", message)


def _trained(run: StageRun) -> SavedRun | None:
    """The trained run: handed over, or read from the train stage's folder (recorded as the
    new run's ``parent``); None when nothing was trained."""
    from dcseg.io.run_output import load_run

    saved, run.handover.trained = run.handover.trained, None
    if saved is not None:
        return saved
    folder = run.folder("train")
    if not (folder / RUN_RECORD).is_file():
        return None
    with run.clock.phase("read"):
        saved = load_run(folder)
    return replace(saved, record={**saved.record, "parent": str(folder)})


def _with_semantic(run: StageRun, saved: SavedRun) -> SavedRun:
    """The run with the job's class-aware masks and vocabulary, or its own when the job gives
    none (re-clustering; a run without any is segmented class-agnostically). The class
    ``assign.unlabelled_id`` names, if any, is unlabelled in either."""
    from dcseg.io.folders import FrameSelection
    from dcseg.io.semantic import read_semantic_maps, read_vocabulary, without_class
    from dcseg.lens import of_record, undistort_semantic

    unlabelled = run.config.pipeline.assign.unlabelled_id
    masks, vocabulary_file = run.inputs.semantic_masks, run.inputs.vocabulary
    if masks is None and vocabulary_file is None:
        # its own masks, or none: objects without classes (class-agnostic)
        own = {name: without_class(m, unlabelled) for name, m in saved.semantic.items()}
        return replace(saved, semantic=own)
    if masks is None or vocabulary_file is None:
        raise InputError.single("semantic masks", "new class-aware masks need a vocabulary")
    vocabulary = read_vocabulary(vocabulary_file)
    names = frozenset(v.name for v in saved.trained.views)
    listed = saved.record.get("capture", {}).get("listed_frames")
    frames = FrameSelection(names, names if listed is None else frozenset(listed))
    semantic = read_semantic_maps(
        masks, vocabulary, size=view_size(saved), frames=frames, unlabelled=unlabelled
    )
    semantic = undistort_semantic(semantic, of_record(saved.record))
    return replace(saved, semantic=semantic, vocabulary=vocabulary)


def _ground_truth(run: StageRun, saved: SavedRun) -> GroundTruth | None:
    from dcseg.io.ground_truth import read_ground_truth

    path = run.inputs.ground_truth
    return None if path is None else read_ground_truth(path, len(saved.vocabulary))


def evaluate(
    saved: SavedRun, labels: Labels, gt: GroundTruth, cfg: PipelineConfig, folder: Path
) -> dict[str, Any]:
    """Evaluate labels against ground truth and write ``folder/metrics.json``."""
    from dcseg.pipeline import evaluate_segmentation

    metrics = evaluate_segmentation(
        saved.trained, labels, saved.semantic, gt, saved.vocabulary, cfg
    )
    write_json(folder / "metrics.json", metrics)
    return metrics


def size_of(saved: SavedRun) -> SceneSize:
    """The sizes the size rules read, of a trained run."""
    width, height = view_size(saved)
    views = len(saved.trained.views)
    return SceneSize(views=views, pixels=width * height, gaussians=len(saved.trained.gaussians))


def view_size(saved: SavedRun) -> tuple[int, int]:
    """The working ``(width, height)`` of a trained run's views."""
    return saved.trained.views[0].width, saved.trained.views[0].height


def _output_size(saved: SavedRun) -> tuple[int, int] | None:
    """The capture's resolution, at which per-view outputs are written (None = the views')."""
    size = saved.record.get("capture", {}).get("output_size")
    return None if size is None else (int(size[0]), int(size[1]))


def link_tree(src: Path, dst: Path, skip: tuple[str, ...]) -> None:
    """Copy a trained state (hard links where possible: state files are never modified)."""
    shutil.copytree(
        src,
        dst,
        ignore=lambda folder, names: [n for n in names if n in skip],
        copy_function=lambda s, d: link_or_copy(Path(s), Path(d)),
    )


SEGMENT = Stage(
    name="segment",
    needs=("train",),
    inputs=("semantic_masks", "vocabulary", "ground_truth"),
    outputs=(
        "scene.ply",
        "scene_labelled.ply",
        "instances.json",
        "labels.json",
        "masks",
        "labels",
        "preview.png",
        "metrics.json",
        RUN_RECORD,
        "state",
    ),
    config=(
        "pipeline.cluster",
        "pipeline.masks",
        "pipeline.assign",
        "pipeline.evaluate",
        "pipeline.scale",
    ),
    parts={"cluster": 0.35, "masks": 0.2, "assign": 0.2, "refine": 0.25},
    run=segment,
)
