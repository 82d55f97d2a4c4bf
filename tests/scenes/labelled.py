"""A small labelled run written in code: a floor and two objects above it, plus noise (what the
viewer shows: ``scene_labelled.ply``, ``instances.json``, ``labels.json``)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import torch

from dcseg.gaussians import SH_C0
from dcseg.io.ply import write_gaussians_ply
from dcseg.types import Vocabulary
from tests.scenes.gaussians import gaussians_at
from tests.scenes.runs import write_objects

VOCABULARY = Vocabulary(("wall", "floor", "box", "ball"))
"""Class ids differ from instance ids, so the two colourings differ; "wall" is absent."""


@dataclass(frozen=True)
class Part:
    """A block of Gaussians: its class, centre, half extents and colour."""

    class_id: int
    centre: tuple[float, float, float]
    half: tuple[float, float, float]
    rgb: tuple[float, float, float]
    count: int


PARTS = (
    Part(1, (0.0, 0.0, 0.0), (1.0, 1.0, 0.01), (0.55, 0.5, 0.45), 2500),  # instance 1: floor
    Part(2, (-0.45, 0.1, 0.2), (0.16, 0.16, 0.16), (0.9, 0.2, 0.2), 1500),  # 2: box
    Part(3, (0.45, -0.1, 0.2), (0.16, 0.16, 0.16), (0.2, 0.3, 0.9), 1500),  # 3: ball
)
NOISE = 60
"""Gaussians without instance or class, scattered above the floor."""


@dataclass(frozen=True)
class LabelledRun:
    folder: Path
    means: np.ndarray
    instance_ids: np.ndarray  # per Gaussian, 1-based, -1 = none

    def centre(self, instance_id: int) -> list[float]:
        return [float(v) for v in self.means[self.instance_ids == instance_id].mean(axis=0)]


def _block(part: Part, rng: np.random.Generator) -> np.ndarray:
    offsets: np.ndarray = rng.uniform(-1, 1, (part.count, 3)) * np.asarray(part.half)
    block: np.ndarray = np.asarray(part.centre) + offsets
    return block


def write_labelled_run(folder: Path, seed: int = 0) -> LabelledRun:
    """Write ``scene_labelled.ply``, ``instances.json`` and ``labels.json`` into ``folder``."""
    rng = np.random.default_rng(seed)
    blocks = [_block(p, rng) for p in PARTS]
    noise = rng.uniform((-1, -1, 0.5), (1, 1, 0.8), (NOISE, 3))
    means = np.concatenate([*blocks, noise]).astype(np.float32)
    per_part = [np.full(p.count, k) for k, p in enumerate(PARTS)]
    clusters = np.concatenate([*per_part, np.full(NOISE, -1)]).astype(np.int64)
    classes = np.array([p.class_id for p in PARTS])
    semantic = np.where(clusters >= 0, classes[np.maximum(clusters, 0)], -1)
    rgb = np.concatenate([np.tile(p.rgb, (p.count, 1)) for p in PARTS] + [np.full((NOISE, 3), 0.9)])
    n = len(means)
    gaussians = gaussians_at(
        torch.from_numpy(means),
        torch.full((n, 3), float(np.log(0.025))),
        torch.full((n,), 3.0),
        torch.from_numpy(((rgb - 0.5) / SH_C0).astype(np.float32)).reshape(n, 1, 3),
    )
    folder.mkdir(parents=True, exist_ok=True)
    instance_ids = np.where(clusters >= 0, clusters + 1, -1)
    extra = {"instance_id": instance_ids, "semantic_id": semantic}
    write_gaussians_ply(folder / "scene_labelled.ply", gaussians, extra=extra)
    write_objects(folder, folder / "scene_labelled.ply", means, clusters, classes, VOCABULARY)
    return LabelledRun(folder, means, instance_ids)


@pytest.fixture(scope="session")
def labelled_run(tmp_path_factory: pytest.TempPathFactory) -> LabelledRun:
    """The labelled run, written once per session (a conftest imports it to use it)."""
    return write_labelled_run(tmp_path_factory.mktemp("viewer") / "run")
