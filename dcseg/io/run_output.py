"""A run's output folder: the exports for apps, and the state that re-segmentation reuses.

Layout of ``OUT/`` (all written into a sibling temporary folder, renamed into place at the end,
so a crashed run never leaves a half-written output)::

    scene.ply, scene_labelled.ply     3DGS PLY; the latter adds int instance_id (object),
                                      semantic_id, cluster_id
    instances.json, labels.json       objects and vocabulary (see dcseg.io.exports)
    masks/<stem>.png, labels/<stem>.png   per-view object ids / class index + 1 (0 = none)
    preview.png                       contact sheet of a few views
    metrics.json                      when ground truth was given
    run.json                          config, per-stage seconds, peak memory, versions, seed
    state/                            trained state (see dcseg.io.run_state), class masks used,
                                      clusters.npz (the cluster level)
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dcseg.errors import InputError
from dcseg.io.captures.jsonfields import load_json
from dcseg.io.exports import (
    instance_records,
    write_instances_json,
    write_labels_json,
    write_preview,
    write_view_maps,
)
from dcseg.io.images import read_image, resize_nearest, write_png
from dcseg.io.jsonfile import write_json
from dcseg.io.ply import read_gaussians_ply, write_gaussians_ply
from dcseg.io.ply_file import open_ply
from dcseg.io.run_state import (
    BlendMemory,
    load_affinity,
    load_views,
    save_affinity,
    save_views,
)
from dcseg.io.semantic import (
    read_semantic_maps,
    read_vocabulary,
    write_semantic_png,
    write_vocabulary,
)
from dcseg.lens import of_record, redistort_labels, remap_nearest
from dcseg.pipeline import TrainedScene
from dcseg.segmentation import Labels, Segmentation
from dcseg.types import SemanticMap, Undistortion, Vocabulary

PREVIEW_VIEWS = 4


@dataclass(frozen=True)
class SavedRun:
    """What a finished run folder gives back for re-clustering or re-classifying."""

    trained: TrainedScene
    semantic: dict[str, SemanticMap]
    vocabulary: Vocabulary
    previews: list[tuple[str, NDArray[np.uint8]]]
    record: dict[str, Any]


def preview_indices(n_views: int) -> list[int]:
    """Indices of up to :data:`PREVIEW_VIEWS` evenly spaced views of ``n_views``."""
    count = min(PREVIEW_VIEWS, n_views)
    return sorted({int(round(i)) for i in np.linspace(0, n_views - 1, count)})


def staging_dir(out: Path) -> Path:
    """A fresh temporary sibling of ``out`` to write into."""
    tmp = out.with_name(f".{out.name}.tmp-{os.getpid()}")
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir(parents=True)
    return tmp


def publish(tmp: Path, out: Path) -> None:
    """Move a finished staging folder to ``out`` (replacing an earlier run there)."""
    if out.exists():
        shutil.rmtree(out)
    tmp.rename(out)


def write_outputs(
    out: Path,
    trained: TrainedScene,
    segmentation: Segmentation,
    vocabulary: Vocabulary,
    previews: Sequence[tuple[str, NDArray[np.uint8]]],
    *,
    size: tuple[int, int] | None = None,
    undistorted: Mapping[str, Undistortion] | None = None,
) -> None:
    """Write every export of a segmentation into ``out`` (an existing, empty folder).

    The object level is what apps get: ``instance_id`` (PLY), ``instances.json`` and
    ``masks/``; the cluster level stays in the PLY's ``cluster_id`` (and ``state/clusters.npz``,
    :func:`save_clusters`). ``size`` is the capture's ``(width, height)``: per-view masks and
    labels are brought to it with nearest neighbour when the views were trained at a lower
    resolution (None = as is); views named in ``undistorted`` (frames whose lens distortion was
    removed when read) are then brought back onto the capture's distorted images.
    """
    g = trained.gaussians
    write_gaussians_ply(out / "scene.ply", g)
    objects = segmentation.instances
    extra = {
        "instance_id": _one_based(objects.ids),
        "semantic_id": segmentation.semantic_ids,
        "cluster_id": _one_based(segmentation.clustering.labels),
    }
    write_gaussians_ply(out / "scene_labelled.ply", g, extra=extra)
    visible = _write_view_maps(out, segmentation, size, undistorted or {})
    means = g.means.detach().cpu().numpy()
    records = instance_records(
        means, objects.ids, objects.classes, objects.scores, visible, vocabulary
    )
    write_instances_json(out / "instances.json", records, out / "scene_labelled.ply")
    write_labels_json(out / "labels.json", vocabulary)
    sheet = [
        (rgb, segmentation.instance_map(name), segmentation.label_maps[name])
        for name, rgb in previews
    ]
    if sheet:
        write_preview(out / "preview.png", sheet, segmentation.n_instances, vocabulary)


def _one_based(labels: NDArray[np.int64]) -> NDArray[np.int64]:
    """Index ``k`` -> id ``k + 1``, -1 stays -1 (the PLY's id convention)."""
    return np.where(labels >= 0, labels + 1, -1)


def _write_view_maps(
    out: Path,
    segmentation: Segmentation,
    size: tuple[int, int] | None,
    undistorted: Mapping[str, Undistortion],
) -> NDArray[np.int64]:
    """Write every view's instance and class maps (at ``size`` if given), one view at a time;
    returns ``[n]`` the number of views in which each object covers at least one pixel."""
    n = segmentation.n_instances
    seen = np.zeros(n, dtype=np.int64)
    for name in segmentation.cluster_maps:
        ids, classes = segmentation.instance_map(name), segmentation.label_maps[name]
        present = np.unique(ids[ids >= 0])
        seen[present[present < n]] += 1
        if size is not None:
            ids, classes = resize_nearest(ids, size), resize_nearest(classes, size)
        if name in undistorted:
            lens = undistorted[name]
            ids, classes = redistort_labels(ids, lens), redistort_labels(classes, lens)
        write_view_maps(out, name, ids, classes)
    return seen


def save_clusters(state: Path, segmentation: Segmentation) -> None:
    """Write ``state/clusters.npz``: the cluster level (labels, centres, classes, object)."""
    state.mkdir(parents=True, exist_ok=True)
    c, a = segmentation.clustering, segmentation.assignment
    np.savez_compressed(
        state / "clusters.npz",
        labels=c.labels,
        centers=c.centers,
        classes=a.labels,
        scores=a.scores,
        instance=segmentation.instances.of_cluster,
    )


def save_state(
    out: Path,
    trained: TrainedScene,
    semantic: Mapping[str, SemanticMap],
    vocabulary: Vocabulary | None,
    previews: Sequence[tuple[str, NDArray[np.uint8]]],
) -> None:
    """Write ``out/state/``: everything re-clustering and re-classifying need.

    Without a vocabulary (a trained-only run) no class-aware masks are stored.
    """
    state = out / "state"
    state.mkdir(parents=True, exist_ok=True)
    write_gaussians_ply(state / "gaussians.ply", trained.gaussians)
    save_affinity(state / "affinity.npz", trained.affinity)
    save_views(state, trained.views)
    if vocabulary is not None:
        save_semantic(state, semantic, vocabulary)
    for i, (_, rgb) in enumerate(previews):
        write_png(state / "preview" / f"{i}.png", rgb)
    names = [name for name, _ in previews]
    write_json(state / "preview.json", {"views": names})


def save_semantic(state: Path, semantic: Mapping[str, SemanticMap], vocabulary: Vocabulary) -> None:
    """Write the class masks a segmentation used, and their vocabulary, into ``state``."""
    folder = state / "semantic"
    if folder.exists():
        shutil.rmtree(folder)
    for name, m in semantic.items():
        write_semantic_png(folder / f"{name}.png", m, len(vocabulary))
    folder.mkdir(parents=True, exist_ok=True)
    write_vocabulary(state / "vocabulary.json", vocabulary)


def load_run(run: Path, memory_mb: int = 0) -> SavedRun:
    """Read a finished run folder's state; raises InputError naming what is missing.

    ``memory_mb``: how much of the blending-weight cache to hold in memory once read
    (:class:`~dcseg.io.run_state.BlendMemory`). 0, the default, reads each view from its file
    on every use: the files just written or read sit in the operating system's page cache, and
    reading them again (~7 GB/s) cost less than holding them, which doubled the process's
    fresh memory. Whole ``dcseg recluster`` of a 40-view 320x240 run, interleaved pairs:
    8.9 s and 0.70 GB peak against 13.4 s and 1.36 GB holding all 40 views (2048 MB).
    """
    state = run / "state"
    if not (run / "run.json").is_file() or not state.is_dir():
        raise InputError.single(str(run), "not a dcseg run folder (no run.json and state/)")
    gaussians = read_gaussians_ply(state / "gaussians.ply")
    trained = TrainedScene(
        gaussians,
        load_affinity(state / "affinity.npz"),
        tuple(load_views(state, BlendMemory(memory_mb * 2**20))),
    )
    vocabulary, semantic = Vocabulary(()), {}
    if (state / "vocabulary.json").is_file():  # absent in trained-only runs
        vocabulary = read_vocabulary(state / "vocabulary.json")
        semantic = read_semantic_maps(state / "semantic", vocabulary)
    preview = load_json(state / "preview.json", str(state / "preview.json"))
    names = preview.get("views") if isinstance(preview, dict) else None
    if not isinstance(names, list):
        raise InputError.single(str(state / "preview.json"), 'expected {"views": [names]}')
    previews = [(str(n), read_image(state / "preview" / f"{i}.png")) for i, n in enumerate(names)]
    return SavedRun(trained, semantic, vocabulary, previews, _record(run))


def _record(run: Path) -> dict[str, Any]:
    """``run.json`` as a dict (an InputError naming it otherwise)."""
    record = load_json(run / "run.json", str(run / "run.json"))
    if not isinstance(record, dict):
        raise InputError.single(str(run / "run.json"), "expected a JSON object")
    return record


def _undistortions(run: Path) -> dict[str, Undistortion]:
    """The frames of a run whose lens distortion was removed (``run.json``), by name."""
    return of_record(_record(run))


def load_labels(run: Path, names: Sequence[str], size: tuple[int, int] | None = None) -> Labels:
    """Read a run's exported labels back: ``semantic_id`` and ``instance_id`` per Gaussian and
    ``labels/`` maps.

    ``size``: the views' ``(width, height)``; maps written at the capture's resolution are
    brought back to it with nearest neighbour (exact for the integer factors of a plan), maps
    written onto distorted images (``run.json`` ``capture.undistortion``) undistorted first.
    """
    path = run / "scene_labelled.ply"
    ply = open_ply(path, str(path))
    try:
        vertex = ply["vertex"]
        semantic_ids = np.asarray(vertex["semantic_id"], dtype=np.int64)
        one_based = np.asarray(vertex["instance_id"], dtype=np.int64)
    except (ValueError, KeyError) as error:
        raise InputError.single(str(path), f"cannot read semantic_id: {error}") from None
    maps = {n: read_image(run / "labels" / f"{n}.png").astype(np.int32) - 1 for n in names}
    undistorted = _undistortions(run)
    maps = {n: remap_nearest(m, undistorted[n]) if n in undistorted else m for n, m in maps.items()}
    if size is not None:
        maps = {n: resize_nearest(m, size) for n, m in maps.items()}
    return Labels(semantic_ids, maps, np.where(one_based > 0, one_based - 1, -1))
