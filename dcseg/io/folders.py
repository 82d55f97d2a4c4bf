"""Per-frame entries of a mask folder, matched to frames by file stem."""

from __future__ import annotations

import logging
from collections.abc import Callable
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
