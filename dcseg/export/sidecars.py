"""The JSON files next to every export: the object table of the format, and ``frame.json``."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from dcseg.export.appearance import palette_colours
from dcseg.export.depth import poses
from dcseg.export.frame import describe_frame
from dcseg.export.plan import ExportPlan, Written
from dcseg.io.jsonfile import write_json

FRAME_FILE = "frame.json"
APPLIED_IN = (
    "glb: scene.glb and instance_<k>.glb (baked into positions, rotations and SH)",
    "glb-mesh: scene_mesh.glb (every node's matrix)",
    "spz: scene.spz and instance_<k>.spz (baked into positions, rotations and SH: SPZ's RUB)",
    "usdz: scene.usdz and instance_<k>.usdz (baked into the points; the stage is Y-up)",
)
"""Where ``frame.json``'s matrix is applied (every other file keeps world coordinates)."""


def sidecar_name(fmt: str) -> str:
    """``instances.<fmt>.json``: one per format, so exports of several formats share a folder."""
    return f"instances.{fmt}.json"


def write_sidecars(plan: ExportPlan, folder: Path, fmt: str, written: Written) -> list[str]:
    """Write ``instances.<fmt>.json`` and ``frame.json`` into ``folder``; returns their names."""
    write_json(folder / sidecar_name(fmt), instance_table(plan, fmt, written))
    c2w = poses(plan.run.path, plan.options.capture)
    write_json(folder / FRAME_FILE, describe_frame(c2w, list(APPLIED_IN)))
    return [sidecar_name(fmt), FRAME_FILE]


def instance_table(plan: ExportPlan, fmt: str, written: Written) -> dict[str, Any]:
    """The selected objects' records, each with its file, palette colours and Gaussian range."""
    run = plan.run
    n = max((int(r["id"]) for r in run.instances), default=0)
    ids = np.array(plan.ids, dtype=np.int64)
    rgb = palette_colours(ids, 1, n).tolist()
    class_rgb = palette_colours(np.arange(len(run.classes)), 0, len(run.classes)).tolist()
    rows = []
    for record, colour in zip(plan.records, rgb, strict=True):
        k = int(record["id"])
        extra = {"file": written.per_instance.get(k), "rgb": colour}
        if written.ranges:
            extra["gaussians"] = written.ranges.get(str(k))
        if fmt in ("glb", "glb-mesh", "usdz"):
            extra["node"] = written.nodes.get(k)
        rows.append({**record, **extra})
    return {
        "run": str(run.path),
        "format": fmt,
        "scene": written.scene,
        "unassigned_gaussians": written.ranges.get("none"),
        **({"labels": written.labels} if written.labels else {}),
        "frame": FRAME_FILE,
        "classes": [{"id": i, "name": c, "rgb": class_rgb[i]} for i, c in enumerate(run.classes)],
        "instances": rows,
    }
