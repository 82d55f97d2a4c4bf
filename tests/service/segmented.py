"""A segmented job's outputs built in code: a labelled 3DGS PLY of a few objects, its
``instances.json`` (records derived from the PLY, as ``dcseg.io.exports`` derives them) and
``labels.json``; and a helper that runs a job whose stages write them."""

from __future__ import annotations

import io
import json
from typing import Any

import numpy as np
from plyfile import PlyData, PlyElement

from tests.service.conftest import AUTH_A, state_of
from tests.worker.fakes import FakeStage
from worker.execute import execute_job

VOCABULARY = ("chair", "table", "lamp")
OBJECTS = [  # (instance id, class index or -1, score, centre, Gaussians)
    (1, 0, 0.9, (0.0, 0.0, 1.0), 40),
    (2, 1, 0.8, (1.0, 0.0, 1.0), 30),
    (3, 0, 0.4, (0.0, 1.0, 1.0), 20),
    (4, -1, 0.0, (1.0, 1.0, 2.0), 10),
    (5, 2, 0.7, (2.0, 0.0, 1.0), 15),
]


def _columns(seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    means, ids, classes = [], [], []
    for k, cls, _, centre, n in OBJECTS:
        means.append(np.asarray(centre) + rng.normal(0, 0.05, (n, 3)))
        ids += [k] * n
        classes += [cls] * n
    xyz = np.concatenate(means).astype(np.float32)
    n = len(xyz)
    cols: dict[str, np.ndarray] = {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2]}
    for name in ("nx", "ny", "nz"):
        cols[name] = np.zeros(n, np.float32)
    for i in range(3):
        cols[f"f_dc_{i}"] = rng.normal(0, 0.5, n).astype(np.float32)
    cols["opacity"] = np.full(n, 2.0, np.float32)
    for i in range(3):
        cols[f"scale_{i}"] = np.full(n, -4.0, np.float32)
    cols["rot_0"] = np.ones(n, np.float32)
    for i in (1, 2, 3):
        cols[f"rot_{i}"] = np.zeros(n, np.float32)
    cols["instance_id"] = np.asarray(ids, np.int32)
    cols["semantic_id"] = np.asarray(classes, np.int32)
    return cols


def labelled_ply() -> bytes:
    cols = _columns()
    dtype = [(name, "<i4" if c.dtype == np.int32 else "<f4") for name, c in cols.items()]
    records = np.empty(len(cols["x"]), dtype=dtype)
    for name, c in cols.items():
        records[name] = c
    buffer = io.BytesIO()
    PlyData([PlyElement.describe(records, "vertex")], text=False).write(buffer)
    return buffer.getvalue()


def instance_records() -> list[dict[str, Any]]:
    cols = _columns()
    xyz = np.stack([cols["x"], cols["y"], cols["z"]], axis=1)
    out = []
    for k, cls, score, _, n in OBJECTS:
        members = xyz[cols["instance_id"] == k]
        out.append(
            {
                "id": k,
                "label": VOCABULARY[cls] if cls >= 0 else None,
                "label_id": cls,
                "score": score,
                "n_gaussians": n,
                "centroid": [round(float(v), 6) for v in members.mean(0)],
                "bbox_min": [round(float(v), 6) for v in members.min(0)],
                "bbox_max": [round(float(v), 6) for v in members.max(0)],
                "n_views": 3,
            }
        )
    return out


def segment_files() -> dict[str, bytes]:
    """The files of a finished ``segment`` stage that the instance routes read."""
    import hashlib

    ply = labelled_ply()
    body = {
        "scene": "scene_labelled.ply",
        "scene_sha256": hashlib.sha256(ply).hexdigest(),
        "instances": instance_records(),
    }
    labels = {"labels": [{"id": i, "name": n} for i, n in enumerate(VOCABULARY)]}
    return {
        "scene_labelled.ply": ply,
        "instances.json": json.dumps(body).encode(),
        "labels.json": json.dumps(labels).encode(),
    }


def run_segmented_job(client: Any, upload_id: str, files: dict[str, bytes] | None = None) -> str:
    """A succeeded job whose ``segment`` stage wrote ``files`` (default :func:`segment_files`)."""
    state = state_of(client)
    job = client.post("/v1/jobs", json={"upload_id": upload_id}, headers=AUTH_A).json()
    stages = [FakeStage("segment", files=segment_files() if files is None else files, steps=1)]
    assert execute_job(job["id"], state.store, state.settings, stages=stages) == "succeeded"
    return str(job["id"])
