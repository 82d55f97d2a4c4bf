"""The input files of one job: a capture and, beside it, masks, vocabulary and ground truth."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from dcseg.errors import InputError
from dcseg.io.bundle import BUNDLE_LAYOUT, bundle_paths

MASK_INPUTS = ("agnostic_masks", "semantic_masks", "vocabulary")
"""The inputs the train and segment stages need (a capture alone is only reconstructed)."""


@dataclass(frozen=True)
class RunInputs:
    """Where the inputs of one job are; only ``capture`` is required.

    Attributes:
        capture: a capture folder, archive or file in any layout dcseg reads.
        agnostic_masks, semantic_masks, vocabulary: the 2D masks and their vocabulary; the
            train and segment stages skip (saying why) when any is missing.
        ground_truth: a ground-truth PLY to evaluate against.
        scene: Gaussians already fitted to this capture (``scene.ply``, with the refined
            poses in a ``poses.json`` beside it, if any): the reconstruct stage uses them
            instead of fitting new ones.
    """

    capture: Path
    agnostic_masks: Path | None = None
    semantic_masks: Path | None = None
    vocabulary: Path | None = None
    ground_truth: Path | None = None
    scene: Path | None = None

    @classmethod
    def from_bundle(
        cls, root: Path, *, scene: Path | None = None, complete: bool = True
    ) -> RunInputs:
        """The inputs of a bundle folder (:data:`dcseg.io.bundle.BUNDLE_LAYOUT`).

        ``complete``: masks and vocabulary are required (InputError names what is missing);
        False takes what the bundle has (ground truth is always optional)."""
        found = bundle_paths(root)
        inputs = cls(
            capture=root,
            agnostic_masks=found["agnostic_masks"],
            semantic_masks=found["semantic_masks"],
            vocabulary=found["vocabulary"],
            ground_truth=found["ground_truth"],
            scene=scene,
        )
        missing = inputs.missing()
        if complete and missing:
            raise InputError.single(str(root), f"the bundle has no {describe_missing(missing)}")
        return inputs

    def missing(self) -> list[str]:
        """The names of :data:`MASK_INPUTS` not given."""
        return [name for name in MASK_INPUTS if getattr(self, name) is None]

    def describe(self) -> dict[str, str | None]:
        """Each input's path as text (None = not given), for ``run.json``."""
        names = ("capture", *MASK_INPUTS, "ground_truth", "scene")
        return {name: _text(getattr(self, name)) for name in names}


def describe_missing(names: list[str]) -> str:
    """``agnostic_masks (masks/agnostic), ...``: the missing inputs with their bundle paths."""
    return ", ".join(f"{n} ({' or '.join(BUNDLE_LAYOUT[n])})" for n in names)


def _text(path: Path | None) -> str | None:
    return None if path is None else str(path)
