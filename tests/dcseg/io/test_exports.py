"""Export files: instances.json, labels.json, per-view maps and the preview sheet."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from dcseg.io.exports import (
    colourise,
    instance_records,
    palette,
    sha256_file,
    write_instances_json,
    write_labels_json,
    write_preview,
    write_view_maps,
)
from dcseg.io.images import read_image
from dcseg.types import Vocabulary

VOCAB = Vocabulary(("wall", "floor", "duck"))


def test_instance_records_summarise_clusters() -> None:
    means = np.array([[0, 0, 0], [2, 0, 0], [5, 5, 5], [9, 9, 9.0]])
    ids = np.array([0, 0, 2, -1])
    records = instance_records(
        means,
        ids,
        cluster_classes=np.array([2, 1, -1]),
        cluster_scores=np.array([0.9, 0.5, 0.0]),
        cluster_views=np.array([4, 0, 1]),
        vocabulary=VOCAB,
    )
    # Cluster 1 has no Gaussians left: no record. Ids are 1-based.
    assert [r.id for r in records] == [1, 3]
    duck, unlabelled = records
    assert (duck.label, duck.label_id, duck.n_gaussians, duck.n_views) == ("duck", 2, 2, 4)
    assert duck.centroid == [1.0, 0.0, 0.0]
    assert (duck.bbox_min, duck.bbox_max) == ([0.0, 0.0, 0.0], [2.0, 0.0, 0.0])
    assert unlabelled.label is None and unlabelled.label_id == -1


def test_instances_json_records_the_ply_hash(tmp_path: Path) -> None:
    ply = tmp_path / "scene_labelled.ply"
    ply.write_bytes(b"ply\nfake")
    records = instance_records(
        np.zeros((1, 3)), np.array([0]), np.array([0]), np.array([1.0]), np.array([1]), VOCAB
    )
    write_instances_json(tmp_path / "instances.json", records, ply)
    body = json.loads((tmp_path / "instances.json").read_text())
    assert body["scene_sha256"] == sha256_file(ply)
    assert body["instances"][0]["label"] == "wall"
    write_labels_json(tmp_path / "labels.json", VOCAB)
    labels = json.loads((tmp_path / "labels.json").read_text())["labels"]
    assert labels[2] == {"id": 2, "name": "duck"}


def test_view_maps_use_zero_for_none(tmp_path: Path) -> None:
    instances = np.array([[-1, 0], [4, 1]])
    classes = np.array([[2, -1], [0, 0]])
    write_view_maps(tmp_path, "seq/frame", instances, classes)
    masks = read_image(tmp_path / "masks" / "seq" / "frame.png")
    labels = read_image(tmp_path / "labels" / "seq" / "frame.png")
    assert masks.dtype == np.uint16 and masks.tolist() == [[0, 1], [5, 2]]
    assert labels.tolist() == [[3, 0], [1, 1]]


def test_palette_distinct_and_none_is_black() -> None:
    colours = palette(20)
    assert len({tuple(c) for c in colours}) == 20
    image = colourise(np.array([[-1, 3]]), 20)
    assert image[0, 0].tolist() == [0, 0, 0] and image[0, 1].tolist() == colours[3].tolist()


def test_preview_sheet_layout(tmp_path: Path) -> None:
    rgb = np.full((12, 16, 3), 200, np.uint8)
    inst = np.zeros((12, 16), np.int64)
    cls = np.full((12, 16), 2)
    write_preview(tmp_path / "preview.png", [(rgb, inst, cls), (rgb, inst - 1, cls)], 1, VOCAB)
    sheet = read_image(tmp_path / "preview.png")
    assert sheet.shape[1] == 48 and sheet.shape[0] > 24
