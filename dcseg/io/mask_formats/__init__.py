"""Which mask format a path holds, decided once for the class-agnostic and the class-map reader.

A path given as ``--agnostic-masks`` / ``--semantic-masks`` (or a bundle's ``masks/agnostic``,
``masks/semantic``) is one of:

* ``coco-instances``: one COCO instance JSON for all frames (``images``, ``annotations`` with
  polygon or RLE ``segmentation``), given as the file or as the folder holding it;
* ``coco-panoptic``: one COCO panoptic JSON (``annotations`` with ``file_name`` and
  ``segments_info``) with its PNGs beside it or in the folder named after it;
* ``panoptic-pairs``: per frame ``<stem>.png`` (panoptic ids) and ``<stem>.json`` (its
  ``segments_info``: a list, or an object with that key), as detectron2 users save them;
* ``per-frame``: one entry per frame (SAM JSON, Grounded-SAM-2 JSON, SAM PNG folder, label map,
  palette PNG, class map, ``[M, H, W]`` stack), each read by its own extension and header.

Only JSON files are opened to decide (images are not decoded), so detection is cheap enough to
run before every read and in ``dcseg validate``.
"""

from __future__ import annotations

import json
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from dcseg.errors import InputError

__all__ = [
    "COCO_INSTANCES",
    "COCO_PANOPTIC",
    "PANOPTIC_PAIRS",
    "PER_FRAME",
    "MaskLayout",
    "describe_layout",
    "detect_masks",
    "entry_format",
    "load_json",
]

COCO_INSTANCES = "coco-instances"
COCO_PANOPTIC = "coco-panoptic"
PANOPTIC_PAIRS = "panoptic-pairs"
PER_FRAME = "per-frame"


@dataclass(frozen=True)
class MaskLayout:
    """The format of one mask path.

    Attributes:
        kind: one of :data:`COCO_INSTANCES`, :data:`COCO_PANOPTIC`, :data:`PANOPTIC_PAIRS`,
            :data:`PER_FRAME`.
        path: the path as given (a folder, or the COCO JSON file itself).
        index: the COCO JSON file (COCO kinds only).
        data: its parsed content (COCO kinds only), so readers do not parse it twice.
    """

    kind: str
    path: Path
    index: Path | None = None
    data: Any = field(default=None, repr=False, compare=False)

    @property
    def root(self) -> Path:
        """The folder files are named relative to in messages."""
        return self.path.parent


def detect_masks(path: Path) -> MaskLayout:
    """The format of the masks at ``path`` (see the module docstring).

    Raises:
        InputError: ``path`` does not exist, or is a file other than a COCO JSON.
    """
    if path.is_file():
        if path.suffix.lower() != ".json":
            reason = "expected a folder of masks or a COCO JSON file"
            raise InputError.single(str(path), reason)
        data = load_json(path, path.parent)
        return MaskLayout(_coco_kind(data, path, path.parent), path, path, data)
    if not path.is_dir():
        raise InputError.single(str(path), "mask folder not found (or not a folder)")
    files = {p.name: p for p in path.iterdir() if not p.name.startswith(".") and p.is_file()}
    stems = Counter(Path(name).stem for name in files)
    objects = [
        file
        for file in sorted(files.values())
        if file.suffix.lower() == ".json" and stems[file.stem] == 1 and _starts_with(file, b"{")
    ]
    if len(objects) == 1:  # one dataset file; several are per-frame records (Grounded-SAM-2)
        data = load_json(objects[0], path.parent)
        if _is_coco(data):
            return MaskLayout(_coco_kind(data, objects[0], path.parent), path, objects[0], data)
    for file in sorted(files.values()):
        png = file.with_suffix(".png")
        if file.suffix.lower() == ".json" and png.name in files and _is_segments_info(file):
            return MaskLayout(PANOPTIC_PAIRS, path)
    return MaskLayout(PER_FRAME, path)


def load_json(path: Path, root: Path) -> Any:
    """Parse a JSON file; InputError naming it (relative to ``root``) and the line if not."""
    from dcseg.io.images import display_path

    shown = display_path(path, root)
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as err:
        reason = f"malformed JSON at line {err.lineno}, column {err.colno}: {err.msg}"
        raise InputError.single(shown, reason) from err
    except (OSError, UnicodeDecodeError) as err:
        raise InputError.single(shown, f"cannot read file: {err}") from err


def _is_coco(data: Any) -> bool:
    """A COCO dataset file: ``annotations`` with ``images`` (instances), or with
    ``segments_info`` (panoptic; DEVA's ``pred.json`` lists no images). A per-frame
    Grounded-SAM-2 result has ``annotations`` only."""
    if not isinstance(data, dict) or not isinstance(data.get("annotations"), list):
        return False
    panoptic = any(isinstance(a, dict) and "segments_info" in a for a in data["annotations"])
    return panoptic or "images" in data


def _coco_kind(data: Any, path: Path, root: Path) -> str:
    """COCO panoptic when any annotation has ``segments_info``, else COCO instances."""
    from dcseg.io.images import display_path

    annotations = data.get("annotations") if isinstance(data, dict) else None
    if not isinstance(annotations, list):
        reason = "expected a COCO JSON object with an 'annotations' list"
        raise InputError.single(display_path(path, root), reason)
    panoptic = any(isinstance(a, dict) and "segments_info" in a for a in annotations)
    return COCO_PANOPTIC if panoptic else COCO_INSTANCES


def _starts_with(path: Path, opening: bytes) -> bool:
    try:
        with path.open("rb") as handle:
            head = handle.read(256)
    except OSError:
        return False
    return head.lstrip(b"\xef\xbb\xbf \t\r\n").startswith(opening)


def _is_segments_info(path: Path) -> bool:
    """A per-frame panoptic JSON: ``{"segments_info": [...]}`` or a list of segments with
    ``id`` and ``category_id`` (SAM's lists have ``segmentation`` instead)."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return False
    if isinstance(data, dict):
        return "segments_info" in data
    first = data[0] if isinstance(data, list) and data else None
    return isinstance(first, dict) and "category_id" in first and "segmentation" not in first


def entry_format(entry: Path) -> str | None:
    """The format of one per-frame entry, by extension and header; None = not a mask entry."""
    suffix = entry.suffix.lower()
    if entry.is_dir():
        return "SAM PNG folder"
    if suffix == ".json":
        return "Grounded-SAM JSON" if _starts_with(entry, b"{") else "SAM JSON"
    if suffix == ".png":
        from dcseg.io.mask_formats.palette import is_palette_png

        return "palette PNG" if is_palette_png(entry) else "PNG map"
    if suffix == ".npz":
        return "NPZ mask stack"
    if suffix == ".npy":
        return "NPY mask stack" if _npy_ndim(entry) in (3, 4) else "NPY map"
    return None


def _npy_ndim(path: Path) -> int | None:
    import numpy as np

    try:
        return int(np.load(path, mmap_mode="r", allow_pickle=False).ndim)
    except (OSError, ValueError, EOFError):
        return None


def describe_layout(layout: MaskLayout) -> str:
    """One line for ``dcseg validate``: the kind and, per frame, which entry formats occur."""
    if layout.kind != PER_FRAME:
        named = f" ({layout.index.name})" if layout.index is not None else ""
        return f"{layout.kind}{named}"
    counts = Counter(
        kind
        for entry in sorted(layout.path.iterdir())
        if not entry.name.startswith(".") and (kind := entry_format(entry)) is not None
    )
    listed = ", ".join(f"{kind} x{n}" for kind, n in sorted(counts.items()))
    return f"{PER_FRAME}: {listed or 'no entries'}"
