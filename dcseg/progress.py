"""The one progress callback type of dcseg: ``on_progress(stage, fraction, message)``.

Every long step reports through it: the job stages (:mod:`dcseg.stages`), their library
steps (reconstruction, cache, affinity, cluster, masks, assign, refine), the CLI's bars
(:class:`dcseg.cli._progress.StageBars`) and the worker's store updates. ``stage`` names what
is running, ``fraction`` is how far it is (0-1), ``message`` says what it just did.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

Progress = Callable[[str, float, str], None]
"""``on_progress(stage, fraction, message)``."""


def quiet(stage: str, fraction: float, message: str) -> None:
    """A :data:`Progress` that reports nothing."""
    return None


def steps(report: Progress, stage: str) -> Callable[[int, int, float], None]:
    """A per-step callback (``step, total, loss``, as optimisation loops count) reporting to
    ``report`` as ``stage``."""

    def step(done: int, total: int, loss: float) -> None:
        report(stage, done / max(total, 1), f"step {done}/{total} loss {loss:.4f}")

    return step


def weighted(report: Progress, stage: str, parts: Mapping[str, float]) -> Progress:
    """Fold a stage's parts into one fraction of ``stage``.

    ``parts`` gives each part's share of the stage's time, in the order they run (e.g. the
    train stage: cache 0.1, affinity 0.9); reports of a part not listed are dropped. The
    message says which part reported.
    """
    order = list(parts)

    def fold(part: str, fraction: float, message: str) -> None:
        if part not in parts:
            return
        done = sum(parts[p] for p in order[: order.index(part)])
        report(stage, done + parts[part] * fraction, f"{part}: {message}")

    return fold
