"""Per-frame entries of a mask folder, matched to frames by file stem."""

from __future__ import annotations

import logging
import os
import shutil
from collections.abc import Callable, Collection
from dataclasses import dataclass
from pathlib import Path
from typing import TypeVar

from dcseg.errors import Problem
from dcseg.io.images import display_path

logger = logging.getLogger(__name__)

T = TypeVar("T")

PART_SEPARATORS = (".", "-", "_")
"""What joins a frame's name and a part name in an entry's stem: ``frame-000000.segm``
(7-Scenes-style part names, Amazon Picking Challenge), ``000001-label`` (YCB-Video),
``0001_mask``."""


def entries_by_stem(
    folder: Path, stem_of: Callable[[Path], str | None], what: str
) -> tuple[dict[str, Path], list[Problem]]:
    """Map each frame stem to its entry in ``folder``.

    Args:
        folder: the mask folder.
        stem_of: the frame stem an entry stands for, or None to ignore the entry.
        what: what the entries are, for messages (e.g. ``"masks"``).

    Returns:
        ``{stem: entry}`` and a problem for every stem given in more than one format.
    """
    by_stem: dict[str, list[Path]] = {}
    for entry in sorted(folder.iterdir()):
        stem = None if entry.name.startswith(".") else stem_of(entry)
        if stem is None:
            logger.debug("ignoring %s: not %s", entry, what)
            continue
        by_stem.setdefault(stem, []).append(entry)
    problems = [
        Problem(
            display_path(paths[0], folder.parent),
            f"frame {stem!r} has {what} in several formats: "
            + ", ".join(display_path(p, folder.parent) for p in paths),
        )
        for stem, paths in by_stem.items()
        if len(paths) > 1
    ]
    return {s: p[0] for s, p in by_stem.items() if len(p) == 1}, problems


def frame_of(stem: str, frames: Collection[str]) -> str | None:
    """The frame an entry named ``stem`` belongs to: the frame of that name, else the frame
    whose name the stem extends by one alphabetic part (:data:`PART_SEPARATORS`); None for
    neither.

    Example:
        >>> frame_of("frame-000000.segm", {"frame-000000"}), frame_of("7-label", {"7"})
        ('frame-000000', '7')
        >>> frame_of("frame-000001", {"frame-000000"}) is None  # a number is not a part
        True
    """
    if stem in frames:
        return stem
    for separator in PART_SEPARATORS:
        head, found, part = stem.rpartition(separator)
        if found and part.isalpha() and head in frames:
            return head
    return None


def by_frame(
    entries: dict[str, T], frames: Collection[str], folder: Path, what: str
) -> tuple[dict[str, T], list[Problem]]:
    """``entries`` keyed by the frames they belong to (:func:`frame_of`; an entry of no frame
    keeps its stem), and a problem for each frame that several entries claim."""
    claims: dict[str, list[str]] = {}
    for stem in entries:
        claims.setdefault(frame_of(stem, frames) or stem, []).append(stem)
    problems = [
        Problem(
            display_path(folder, folder.parent),
            f"frame {frame!r} has several {what}: " + ", ".join(sorted(stems)),
        )
        for frame, stems in sorted(claims.items())
        if len(stems) > 1
    ]
    named = {frame: entries[stems[0]] for frame, stems in claims.items() if len(stems) == 1}
    return named, problems


@dataclass(frozen=True)
class FrameSelection:
    """The frames whose entries a reader reads (a run's keyframes, :mod:`dcseg.io.captures.plan`).

    Attributes:
        read: the frames read; entries of other frames are skipped without being decoded.
        listed: every frame of the capture; an entry of a frame outside it is a problem.
            None = not checked.
    """

    read: frozenset[str]
    listed: frozenset[str] | None = None

    def pick(
        self, entries: dict[str, T], folder: Path, what: str
    ) -> tuple[dict[str, T], list[Problem]]:
        """The entries of the frames read, keyed by frame (:func:`by_frame`: an entry's stem
        may add a part name to its frame's, ``frame-000000.segm``), and problems naming
        entries of unknown frames and frames claimed twice."""
        entries, problems = by_frame(entries, self.listed or self.read, folder, what)
        if self.listed is not None:
            extra = sorted(set(entries) - self.listed)
            if extra:
                shown = ", ".join(extra[:5]) + (" ..." if len(extra) > 5 else "")
                where = display_path(folder, folder.parent)
                problems.append(Problem(where, f"{what} for frames the capture lacks: {shown}"))
        kept = {stem: entry for stem, entry in entries.items() if stem in self.read}
        logger.debug("%s: reading %d of %d entries", folder, len(kept), len(entries))
        return kept, problems


def inside(root: Path, name: str) -> Path | None:
    """``root / name`` when ``name`` (a file name a capture's own listing gives) is a relative
    path that stays inside ``root``; None for an absolute path, one that climbs out, or one
    holding a NUL byte (which no file name can)."""
    if "\0" in name or Path(name).is_absolute():
        return None
    if not (root / name).resolve().is_relative_to(root.resolve()):
        return None
    return root / name


def link_or_copy(src: Path, dst: Path) -> None:
    """Hard-link ``src`` to ``dst`` (a copy across file systems), replacing ``dst``; run files
    are never modified in place, so a link is as good as a copy."""
    dst.unlink(missing_ok=True)
    try:
        os.link(src, dst)
    except OSError:
        shutil.copy2(src, dst)
