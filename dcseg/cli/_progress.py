"""Progress bars on stderr: one tqdm bar per pipeline stage."""

from __future__ import annotations

import sys
from types import TracebackType
from typing import Any

STEPS = 1000


class StageBars:
    """A ``Progress`` callback (``(stage, fraction, message)``) drawing one bar per stage."""

    def __init__(self, enabled: bool = True) -> None:
        self.enabled = enabled
        self.stage: str | None = None
        self.bar: Any = None

    def __call__(self, stage: str, fraction: float, message: str) -> None:
        if not self.enabled:
            return
        if stage != self.stage:
            self.close()
            from tqdm import tqdm

            self.stage = stage
            self.bar = tqdm(total=STEPS, desc=f"{stage:>11}", file=sys.stderr, leave=True)
        self.bar.n = min(STEPS, round(fraction * STEPS))
        self.bar.set_postfix_str(message, refresh=False)
        self.bar.refresh()

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
        self.bar, self.stage = None, None

    def __enter__(self) -> StageBars:
        return self

    def __exit__(
        self,
        kind: type[BaseException] | None,
        error: BaseException | None,
        trace: TracebackType | None,
    ) -> None:
        self.close()
