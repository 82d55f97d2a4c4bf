"""Stand-ins for pipeline stages and queues, for service and worker tests."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from worker.execute import StageContext, StageOutcome


@dataclass
class FakeStage:
    """Writes ``files`` after ``steps`` progress reports; ``on_step(i)`` runs before each."""

    name: str
    files: dict[str, bytes] = field(default_factory=lambda: {"out.txt": b"hello"})
    steps: int = 3
    on_step: Callable[[int], None] | None = None
    fail: Exception | None = None
    runs: int = 0

    def key(self, config: dict[str, Any]) -> dict[str, Any]:
        return {"options": config.get("options", {})}

    def run(self, ctx: StageContext, out: Path) -> StageOutcome:
        self.runs += 1
        for i in range(self.steps):
            if self.on_step is not None:
                self.on_step(i)
            ctx.progress((i + 1) / self.steps, f"{self.name}: step {i + 1}/{self.steps}")
        if self.fail is not None:
            raise self.fail
        for name, data in self.files.items():
            (out / name).parent.mkdir(parents=True, exist_ok=True)
            (out / name).write_bytes(data)
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
