"""Stand-ins for pipeline stages and queues, for service and worker tests."""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from worker.stage import Stage, StageContext, StageOutcome


@dataclass
class FakeStage:
    """Writes ``files`` after ``steps`` progress reports; ``on_step(i)`` runs before each and
    ``on_end()`` after the files are written (past the stage's last progress report)."""

    name: str
    files: dict[str, bytes] = field(default_factory=lambda: {"out.txt": b"hello"})
    steps: int = 3
    on_step: Callable[[int], None] | None = None
    fail: Exception | None = None
    on_end: Callable[[], None] | None = None
    runs: int = 0

    def key(self, config: dict[str, Any]) -> dict[str, Any]:
        return {"options": config.get("options", {})}

    def run(self, ctx: StageContext, out: Path) -> StageOutcome:
        self.runs += 1
        for i in range(self.steps):
            if self.on_step is not None:
                self.on_step(i)
            ctx.progress(self.name, (i + 1) / self.steps, f"{self.name}: step {i + 1}/{self.steps}")
        if self.fail is not None:
            raise self.fail
        for name, data in self.files.items():
            (out / name).parent.mkdir(parents=True, exist_ok=True)
            (out / name).write_bytes(data)
        if self.on_end is not None:
            self.on_end()
        return StageOutcome("done", f"{self.name}: done")


@dataclass
class RecordingQueue:
    """A JobQueue that remembers what was enqueued."""

    job_ids: list[str] = field(default_factory=list)
    intact: bool = True
    """False = the broker lost its messages (until :meth:`mark_intact`)."""

    def enqueue(self, job_id: str) -> None:
        self.job_ids.append(job_id)

    def ping(self) -> None:
        return None

    def lost_messages(self) -> bool:
        return not self.intact

    def mark_intact(self) -> None:
        self.intact = True


@dataclass
class SilentStage:
    """Never reports progress: sleeps ``seconds`` in one call (a stage stuck in native code),
    or until ``release`` is set."""

    name: str
    seconds: float = 3600.0
    release: threading.Event | None = None
    runs: int = 0

    def key(self, config: dict[str, Any]) -> dict[str, Any]:
        return {}

    def run(self, ctx: StageContext, out: Path) -> StageOutcome:
        self.runs += 1
        if self.release is not None:
            self.release.wait(self.seconds)
        else:
            time.sleep(self.seconds)
        (out / "late.txt").write_bytes(b"too late")
        return StageOutcome("done", f"{self.name}: done")


def stuck_stages() -> list[Stage]:
    """A finished ``validate`` then a stage that never returns nor reports progress (the
    embedded worker and the Celery test app import this by name)."""
    return [FakeStage("validate"), SilentStage("stuck")]


def slow_stages() -> list[Stage]:
    """``validate``, then ``slow``: ``DCSEG_TEST_SLOW_STEPS`` (default 1000) progress reports
    0.1 s apart."""
    steps = int(os.environ.get("DCSEG_TEST_SLOW_STEPS", "1000"))
    return [FakeStage("validate"), FakeStage("slow", steps=steps, on_step=_nap)]


def _nap(step: int) -> None:
    time.sleep(0.1)
