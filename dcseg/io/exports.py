"""The segmented scene's export files for apps and viewers.

Written into a run's output folder (see the README, "Outputs"):

* ``instances.json``: one record per instance (the fields of
  :class:`~dcseg.io.instance_record.InstanceRecord`) plus the sha256 of the
  ``scene_labelled.ply`` it indexes; ids start at 1.
* ``labels.json``: the vocabulary, ``{"labels": [{"id": i, "name": ...}, ...]}``.
* ``masks/<stem>.png``: uint16 instance id per pixel, 0 = none.
* ``labels/<stem>.png``: uint16 class index + 1 per pixel, 0 = none.
* ``preview.png``: a contact sheet (RGB, instances, labels) of a few views with a class legend.
"""

from __future__ import annotations

import colorsys
import hashlib
import json
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from dcseg.io.images import write_png
from dcseg.io.instance_record import InstanceRecord
from dcseg.types import Vocabulary


def instance_records(
    means: NDArray[np.floating[Any]],
    instance_ids: NDArray[np.integer[Any]],
    cluster_classes: NDArray[np.integer[Any]],
    cluster_scores: NDArray[np.floating[Any]],
    cluster_views: NDArray[np.integer[Any]],
    vocabulary: Vocabulary,
) -> list[InstanceRecord]:
    """Summarise every instance (id k+1 for instance k) that still has Gaussians.

    Args:
        means: ``[N, 3]`` Gaussian centres.
        instance_ids: ``[N]`` instance index per Gaussian (an object, or a cluster), -1 = none.
        cluster_classes: ``[K]`` class index per instance, -1 = unlabelled.
        cluster_scores: ``[K]`` confidence of each instance's class.
        cluster_views: ``[K]`` number of views each instance is seen in.
        vocabulary: the class names.
    """
    records = []
    for k in range(len(cluster_classes)):
        members = means[instance_ids == k]
        if members.shape[0] == 0:
            continue
        label_id = int(cluster_classes[k])
        records.append(
            InstanceRecord(
                id=k + 1,
                label=vocabulary.names[label_id] if label_id >= 0 else None,
                label_id=label_id,
                score=round(float(cluster_scores[k]), 6),
                n_gaussians=int(members.shape[0]),
                centroid=_rounded(members.mean(axis=0)),
                bbox_min=_rounded(members.min(axis=0)),
                bbox_max=_rounded(members.max(axis=0)),
                n_views=int(cluster_views[k]),
            )
        )
    return records


def _rounded(values: NDArray[Any]) -> list[float]:
    return [round(float(v), 6) for v in values]


def sha256_file(path: Path) -> str:
    """Hex sha256 of a file, read in chunks."""
    digest = hashlib.sha256()
    with path.open("rb") as handle:
        for chunk in iter(lambda: handle.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def write_instances_json(path: Path, records: Sequence[InstanceRecord], ply: Path) -> None:
    """Write ``instances.json`` with the sha256 of the PLY whose Gaussians it indexes."""
    body = {
        "scene": ply.name,
        "scene_sha256": sha256_file(ply),
        "instances": [asdict(r) for r in records],
    }
    path.write_text(json.dumps(body, indent=1) + "\n", encoding="utf-8")


def write_labels_json(path: Path, vocabulary: Vocabulary) -> None:
    """Write ``labels.json``: the vocabulary with each class's index."""
    labels = [{"id": i, "name": name} for i, name in enumerate(vocabulary.names)]
    path.write_text(json.dumps({"labels": labels}, indent=1) + "\n", encoding="utf-8")


def write_view_maps(
    out: Path, name: str, instances: NDArray[np.integer[Any]], classes: NDArray[np.integer[Any]]
) -> None:
    """Write ``masks/<name>.png`` (instance id, 0 = none) and ``labels/<name>.png``.

    Args:
        out: the run's output folder.
        name: the frame stem (may contain ``/``).
        instances: ``[H, W]`` cluster index per pixel, -1 = none.
        classes: ``[H, W]`` class index per pixel, -1 = none.
    """
    write_png(out / "masks" / f"{name}.png", (instances + 1).astype(np.uint16))
    write_png(out / "labels" / f"{name}.png", (classes + 1).astype(np.uint16))


def palette(n: int) -> NDArray[np.uint8]:
    """``[n, 3]`` distinct RGB colours (golden-ratio hues), stable for a given index."""
    colours = [colorsys.hsv_to_rgb((i * 0.618034) % 1.0, 0.65, 0.95) for i in range(n)]
    return (np.array(colours, dtype=np.float64).reshape(n, 3) * 255).astype(np.uint8)


def colourise(ids: NDArray[np.integer[Any]], n: int) -> NDArray[np.uint8]:
    """``[H, W]`` ids (-1 = none, drawn black) to ``[H, W, 3]`` RGB."""
    table = np.concatenate([np.zeros((1, 3), np.uint8), palette(max(n, 1))])
    out: NDArray[np.uint8] = table[np.clip(ids, -1, n - 1) + 1]
    return out


def write_preview(
    path: Path,
    views: Sequence[tuple[NDArray[np.uint8], NDArray[Any], NDArray[Any]]],
    n_instances: int,
    vocabulary: Vocabulary,
) -> None:
    """Write a contact sheet: one row per view with RGB | instances | labels, and a legend.

    Args:
        path: the PNG to write.
        views: ``(rgb [H,W,3], instances [H,W], classes [H,W])`` per view, all the same size.
        n_instances: number of instances (for instance colours).
        vocabulary: class names for the legend.
    """
    rows = [
        np.hstack([rgb, colourise(inst, n_instances), colourise(cls, len(vocabulary))])
        for rgb, inst, cls in views
    ]
    sheet = np.vstack(rows)
    present = sorted({int(c) for _, _, cls in views for c in np.unique(cls) if c >= 0})
    legend = _legend(present, vocabulary, sheet.shape[1])
    write_png(path, np.vstack([sheet, legend]))


def _legend(present: Sequence[int], vocabulary: Vocabulary, width: int) -> NDArray[np.uint8]:
    colours = palette(max(len(vocabulary), 1))
    per_row = max(1, width // 150)
    rows = max(1, -(-len(present) // per_row))
    legend = np.full((rows * 22 + 6, width, 3), 255, np.uint8)
    for i, c in enumerate(present):
        x, y = 6 + (i % per_row) * 150, 6 + (i // per_row) * 22
        colour = tuple(int(v) for v in colours[c])
        cv2.rectangle(legend, (x, y), (x + 14, y + 14), colour, thickness=-1)
        cv2.putText(
            legend,
            vocabulary.names[c][:18],
            (x + 20, y + 12),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.4,
            (0, 0, 0),
            1,
            cv2.LINE_AA,
        )
    return legend
