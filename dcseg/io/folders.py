"""Per-frame entries of a mask folder, matched to frames by file stem."""

from __future__ import annotations

import logging
import os
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from dcseg.errors import Problem
from dcseg.io.images import display_path

logger = logging.getLogger(__name__)


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
        self, entries: dict[str, Path], folder: Path, what: str
    ) -> tuple[dict[str, Path], list[Problem]]:
        """The entries of the frames read, and a problem naming entries of unknown frames."""
        problems = []
        if self.listed is not None:
            extra = sorted(set(entries) - self.listed)
            if extra:
                shown = ", ".join(extra[:5]) + (" ..." if len(extra) > 5 else "")
                where = display_path(folder, folder.parent)
                problems.append(Problem(where, f"{what} for frames the capture lacks: {shown}"))
        kept = {stem: path for stem, path in entries.items() if stem in self.read}
        logger.debug("%s: reading %d of %d entries", folder, len(kept), len(entries))
        return kept, problems


def link_or_copy(src: Path, dst: Path) -> None:
    """Hard-link ``src`` to ``dst`` (a copy across file systems), replacing ``dst``; run files
    are never modified in place, so a link is as good as a copy."""
    dst.unlink(missing_ok=True)
    try:
        os.link(src, dst)
    except OSError:
        shutil.copy2(src, dst)
