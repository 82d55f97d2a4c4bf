"""The bundle layout: a capture folder with its masks, vocabulary and ground truth beside it.

Uploads to the service and ``dcseg synth`` outputs use it. Standard library only: the API
process imports it.
"""

from __future__ import annotations

from pathlib import Path

BUNDLE_LAYOUT: dict[str, tuple[str, ...]] = {
    "agnostic_masks": ("masks/agnostic", "masks/panoptic"),
    "semantic_masks": ("masks/semantic", "masks/panoptic"),
    "vocabulary": ("vocabulary.txt", "vocabulary.json"),
    "ground_truth": ("gt/points.ply",),
}
"""Optional inputs by their names under the bundle root (which holds the capture itself in any
layout dcseg reads); the first existing candidate of each is used. ``masks/panoptic`` is one
panoptic source for both kinds of masks (:mod:`dcseg.io.mask_formats.panoptic`)."""


def bundle_paths(root: Path) -> dict[str, Path | None]:
    """``{"capture": root, "agnostic_masks": ..., ...}``, None for inputs the bundle lacks."""
    found: dict[str, Path | None] = {"capture": root}
    for name, candidates in BUNDLE_LAYOUT.items():
        found[name] = next((root / c for c in candidates if (root / c).exists()), None)
    return found
