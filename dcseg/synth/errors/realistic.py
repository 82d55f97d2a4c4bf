"""The ``realistic`` generator: :mod:`dcseg.synth.failures` (the ``realistic`` noise level).

Open-vocabulary class maps with per-scene look-alike confusions shown in most views, rare
objects missed in every view, small objects swallowed by their support, 1/4-resolution maps
that never abstain, on top of per-view noise; SAM-style masks at 1/2 resolution with touching
objects merged and 10-30 % of the objects uncovered per view. ``dcseg synth --noise realistic``
and ``--error-model realistic`` make the same masks.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from dcseg.synth.errors.base import SceneTruth, ViewOutput, ViewTruth
from dcseg.synth.failures import draw_fates, realistic_agnostic, realistic_semantic
from dcseg.synth.noise import NOISE_LEVELS, Failures, NoiseLevel


class RealisticModel:
    """Per-view noise of the ``realistic`` level plus its consistent failures."""

    name = "realistic"

    def __init__(self, level: NoiseLevel | None = None) -> None:
        self.level = NOISE_LEVELS["realistic"] if level is None else level
        failures = self.level.failures
        self.failures = Failures() if failures is None else failures

    def prepare(self, scene: SceneTruth, rng: np.random.Generator) -> Any:
        return draw_fates(scene.instances, self.failures, rng)

    def view(
        self,
        truth: ViewTruth,
        scene: SceneTruth,
        fates: Any,
        agnostic_rng: np.random.Generator,
        semantic_rng: np.random.Generator,
    ) -> ViewOutput:
        ids, level, failures = truth.instance_map, self.level, self.failures
        dense = realistic_agnostic(
            ids, truth.xyz, scene.instances, scene.part_normals, level, failures, agnostic_rng
        )
        classes = realistic_semantic(
            ids, truth.class_map, scene.instances, fates, level, failures, semantic_rng
        )
        return ViewOutput(dense, classes)
