"""Stage time limits: the limit of each stage, and a watchdog for stages stuck without
progress reports (in native code), which the runner of :mod:`worker.execute` arms per stage."""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from types import TracebackType

from jobstore.settings import Settings


class StageTimeout(Exception):
    """A stage ran past its time limit (``DCSEG_STAGE_TIME_LIMIT_S``)."""

    def __init__(self, stage: str, limit_s: float) -> None:
        super().__init__(
            f"stage {stage} exceeded its time limit of {limit_s:g} s "
            "(setting DCSEG_STAGE_TIME_LIMIT_S)"
        )
        self.stage, self.limit_s = stage, limit_s


def stage_time_limit(settings: Settings, stage: str) -> float:
    """The stage's limit in seconds: ``stage_time_limit_s[stage]`` or the default."""
    return settings.stage_time_limit_s.get(stage, settings.stage_time_limit_default_s)


class StageWatchdog:
    """A thread that stops a stage stuck past its time limit without reaching a progress report.

    The runner arms it when a stage starts and disarms it when the stage returns. A stage
    that reports progress is stopped by :meth:`_Runner.check` at its limit; one still running
    ``grace_s`` after it (stuck in native code) makes the watchdog set :attr:`fired` and call
    ``on_overrun`` from its own thread, which fails the job and kills the process where the
    caller allows it.
    """

    def __init__(self, grace_s: float, on_overrun: Callable[[StageTimeout], None]) -> None:
        self.grace_s, self.on_overrun = grace_s, on_overrun
        self.fired: StageTimeout | None = None
        self._armed: tuple[StageTimeout, float] | None = None
        self._closed = False
        self._wake = threading.Condition()
        self._thread = threading.Thread(target=self._loop, name="stage-watchdog", daemon=True)

    def arm(self, stage: str, limit_s: float) -> None:
        with self._wake:
            self._armed = (StageTimeout(stage, limit_s), time.monotonic() + limit_s + self.grace_s)
            self._wake.notify()

    def disarm(self) -> None:
        with self._wake:
            self._armed = None
            self._wake.notify()

    def _due(self) -> StageTimeout | None:
        """Wait (lock held) until the armed stage is overdue or the watchdog is closed."""
        while not self._closed:
            if self._armed is None:
                self._wake.wait()
                continue
            timeout, due_at = self._armed
            left = due_at - time.monotonic()
            if left <= 0:
                return timeout
            self._wake.wait(left if math.isfinite(left) else None)
        return None

    def _loop(self) -> None:
        with self._wake:
            self.fired = self._due()
        if self.fired is not None:
            self.on_overrun(self.fired)

    def __enter__(self) -> StageWatchdog:
        self._thread.start()
        return self

    def __exit__(
        self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        with self._wake:
            self._closed = True
            self._wake.notify()
        self._thread.join()
