"""One export request, resolved: the run, the selected objects, and what a writer produced."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from dcseg.export.options import ExportOptions

if TYPE_CHECKING:  # the package's import stays light (the CLI's --help reads FORMATS)
    from dcseg.export.labelled import LabelledRun


@dataclass(frozen=True)
class ExportPlan:
    """What a format writer is asked to write.

    Attributes:
        run: the finished run.
        records: the selected objects' ``instances.json`` records (all when ``whole``).
        whole: no selection was given: scene-wide files are written as well.
        options: colours, SH degree, mesh settings.
    """

    run: LabelledRun
    records: list[dict[str, Any]]
    whole: bool
    options: ExportOptions

    @property
    def ids(self) -> list[int]:
        return [int(r["id"]) for r in self.records]

    def rows_of(self, instance: int) -> NDArray[np.int64]:
        """Indices of the Gaussians of object ``instance``."""
        return np.flatnonzero(self.run.instance_ids == instance)

    def scene_rows(self) -> tuple[NDArray[np.int64], dict[str, list[int]]]:
        """Every Gaussian, grouped by selected object (in selection order) then the rest, and
        each group's ``[offset, count]`` in that order (keys: object id, ``"none"``)."""
        groups = [self.rows_of(k) for k in self.ids]
        chosen = np.isin(self.run.instance_ids, self.ids)
        groups.append(np.flatnonzero(~chosen))
        ranges: dict[str, list[int]] = {}
        offset = 0
        for key, rows in zip([*map(str, self.ids), "none"], groups, strict=True):
            ranges[key] = [offset, int(len(rows))]
            offset += len(rows)
        return np.concatenate(groups), ranges


@dataclass
class Written:
    """Files a writer produced (names relative to the export folder).

    Attributes:
        files: every file, in writing order.
        per_instance: the file holding each object alone (by object id), if any.
        scene: the scene-wide file, if any.
        ranges: ``[offset, count]`` of each object's Gaussians in ``scene`` (key ``"none"``:
            Gaussians of no selected object), for Gaussian formats.
        nodes: each object's node (GLB) or prim (USDZ) name; meshes: none without a surface.
        labels: the per-Gaussian label sidecar of ``scene`` (PLY: file, columns), if any.
    """

    files: list[str] = field(default_factory=list)
    per_instance: dict[int, str] = field(default_factory=dict)
    scene: str | None = None
    ranges: dict[str, list[int]] = field(default_factory=dict)
    nodes: dict[int, str] = field(default_factory=dict)
    labels: dict[str, Any] = field(default_factory=dict)


def node_extras(record: dict[str, Any]) -> dict[str, Any]:
    """What a GLB node says about its object (mesh and splat GLBs alike)."""
    k, label = int(record["id"]), record.get("label")
    return {
        "instance_id": k,
        "name": f"{label or 'object'}_{k}",
        "label": label,
        "class": label,
        "class_id": int(record.get("label_id", -1)),
        "score": float(record.get("score", 0.0)),
        "n_gaussians": int(record.get("n_gaussians", 0)),
    }
