"""What the worker's runner (:mod:`worker.execute`) asks of a stage: a name, a key and
``run(ctx, out)``; :mod:`worker.stages` wraps the library's stage list in it."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, Protocol

from dcseg.progress import Progress
from jobstore.settings import Settings


@dataclass(frozen=True)
class StageOutcome:
    """What a stage reports when it returns."""

    status: Literal["done", "skipped"] = "done"
    message: str = ""
    details: dict[str, Any] = field(default_factory=dict)


@dataclass
class StageContext:
    """What a stage may use: its inputs, the job's config, and the progress callback."""

    job_id: str
    input_root: Path
    config: dict[str, Any]
    settings: Settings
    progress: Progress
    """``progress(stage, fraction_of_stage, message)`` (the stage's own name); raises to stop
    the stage (cancel, timeout)."""
    log: Callable[[str], None]
    output_root: Path | None = None
    """The job's output folder; finished stages' files are under ``output_root/<stage>/``."""


class Stage(Protocol):
    """One pipeline stage: writes its files into ``out`` and returns an outcome."""

    name: str

    def key(self, config: dict[str, Any]) -> dict[str, Any]:
        """The parameters the stage's output depends on (a derived job reuses the parent's
        output when they are equal)."""
        ...

    def run(self, ctx: StageContext, out: Path) -> StageOutcome: ...
