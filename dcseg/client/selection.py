"""Which of a job's listed files a download fetches: the deliverables, all, or by pattern."""

from __future__ import annotations

from collections.abc import Sequence
from fnmatch import fnmatchcase
from typing import Any

__all__ = ["DELIVERABLES", "choose", "deliverables", "human_size", "matches", "select"]

DELIVERABLES = (
    "segment/scene_labelled.ply",
    "segment/instances.json",
    "segment/labels.json",
    "segment/labels/*",
    "segment/masks/*",
    "segment/metrics.json",
    "segment/preview.png",
    "segment/run.json",
)
"""What a user of a segmented job wants: the labelled Gaussians, the objects, the label maps,
per-view labels and masks, metrics, the preview and the run record. Left out: ``state/`` (the
trained state only ``recluster`` reads, most of the bytes), ``segment/scene.ply`` (the same
Gaussians as ``scene_labelled.ply`` without labels) and the earlier stages' folders."""


def matches(name: str, pattern: str) -> bool:
    """Whether ``pattern`` names the listed path ``name``: a glob (``*`` also crosses ``/``)
    on the whole path, on its trailing part after a ``/`` (``instances.json`` is
    ``segment/instances.json``), or on a folder holding it (``masks`` is ``segment/masks/0.png``).
    """
    pattern = pattern.strip("/")
    return any(
        fnmatchcase(name, form)
        for form in (pattern, f"*/{pattern}", f"{pattern}/*", f"*/{pattern}/*")
    )


def select(items: Sequence[dict[str, Any]], only: Sequence[str] | None) -> list[dict[str, Any]]:
    """The listed files ``only`` names (all when None); ValueError naming unmatched entries."""
    if only is None:
        return list(items)
    missing = [e for e in only if not any(matches(i["name"], e) for i in items)]
    if missing:
        names = ", ".join(i["name"] for i in items) or "none"
        raise ValueError(f"no file named {', '.join(map(repr, missing))} (there are: {names})")
    return [i for i in items if any(matches(i["name"], e) for e in only)]


def deliverables(items: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """The :data:`DELIVERABLES` of a segmented job; every file of a job that did not segment
    (a capture-only job: its report and reconstruction are what there is)."""
    chosen = [i for i in items if any(fnmatchcase(i["name"], p) for p in DELIVERABLES)]
    return chosen or list(items)


def choose(
    items: Sequence[dict[str, Any]], only: Sequence[str] | None = None, everything: bool = False
) -> list[dict[str, Any]]:
    """What a download fetches: ``only``'s files, every file, or the deliverables."""
    if only:
        return select(items, only)
    return list(items) if everything else deliverables(items)


def human_size(size: float) -> str:
    """``1.2 MB`` (decimal units, as file managers show them)."""
    for unit in ("B", "kB", "MB", "GB"):
        if size < 1000 or unit == "GB":
            return f"{size:.0f} {unit}" if unit == "B" else f"{size:.1f} {unit}"
        size /= 1000
    raise AssertionError("unreachable")
