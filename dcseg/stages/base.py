"""What a stage of the job is, what it receives, and what it hands to the next one.

A job is the list :data:`dcseg.stages.STAGES` (validate -> reconstruct -> train -> segment).
Each :class:`Stage` declares its inputs, the earlier stages it reads, the files it writes and
the config sections its result depends on (its cache key), and runs from a :class:`StageRun`:
the job's inputs, the whole typed :class:`~dcseg.config.JobConfig`, its own output folder and
the folders of the stages before it. :func:`dcseg.jobs.run_job` runs the list in one process,
handing products over in memory (:class:`Handover`); the worker runs each stage on its own
and the next one reads the files the last one committed.
"""

from __future__ import annotations

import resource
import time
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field, is_dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from dcseg.config import JobConfig
from dcseg.inputs import RunInputs
from dcseg.progress import Progress, quiet

if TYPE_CHECKING:
    from dcseg.gaussians import Gaussians
    from dcseg.io.captures.plan import CapturePlan
    from dcseg.io.run_output import SavedRun
    from dcseg.types import Capture


class Clock:
    """Seconds per named phase, and the process's peak memory by the end of each phase."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}
        self.peak_mb: dict[str, float] = {}

    @contextmanager
    def phase(self, name: str) -> Iterator[None]:
        start = time.perf_counter()
        yield
        self.seconds[name] = round(self.seconds.get(name, 0.0) + time.perf_counter() - start, 3)
        self.peak_mb[name] = peak_mb()


def peak_mb() -> float:
    """The process's peak resident memory so far (MB)."""
    return round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)


@dataclass
class Handover:
    """Products one stage leaves in memory for the next, when they run in one process.

    Each field is taken (set back to None) by the stage that uses it, so memory is freed as
    soon as possible; a stage whose product is absent reads it from the files of the stage
    that made it (what the worker always does).
    """

    capture: Capture | None = None
    plan: CapturePlan | None = None
    gaussians: Gaussians | None = None
    trained: SavedRun | None = None


@dataclass
class StageRun:
    """Everything a stage receives.

    Attributes:
        inputs: the job's input files.
        config: the job's whole typed config (the stage reads the sections it needs).
        out: the empty folder the stage writes its files into.
        done: the folder of each earlier stage that finished, by name.
        progress: where the stage reports (its parts by name, see :attr:`Stage.parts`).
        device: where reconstruction, the cache's projection and training compute
            (:func:`dcseg.devices.resolve_device`).
        clock: seconds and peak memory per phase (shared by the stages of one process).
        handover: products of earlier stages in this process.
    """

    inputs: RunInputs
    config: JobConfig
    out: Path
    done: Mapping[str, Path] = field(default_factory=dict)
    progress: Progress = quiet
    device: str = "auto"
    clock: Clock = field(default_factory=Clock)
    handover: Handover = field(default_factory=Handover)

    def folder(self, stage: str) -> Path:
        """The output folder of the earlier stage ``stage``."""
        return self.done[stage]


@dataclass(frozen=True)
class StageResult:
    """What a stage reports when it returns: ``skipped`` when its inputs were not given."""

    status: Literal["done", "skipped"]
    message: str


@dataclass(frozen=True)
class Stage:
    """One stage of the job.

    Attributes:
        name: the stage's name (its output folder in the worker, its progress label).
        needs: earlier stages whose files (or handover) it reads.
        inputs: the job inputs (:class:`~dcseg.inputs.RunInputs` fields) it reads.
        outputs: the files and folders it writes into its folder.
        config: the config sections its result depends on, as dotted paths of
            :class:`~dcseg.config.JobConfig` (``"pipeline.affinity"``).
        parts: each part's share of the stage's time, in order (progress of the parts is
            folded into one fraction by :func:`dcseg.progress.weighted`).
        run: does the work.
    """

    name: str
    needs: tuple[str, ...]
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    config: tuple[str, ...]
    parts: Mapping[str, float]
    run: Callable[[StageRun], StageResult]


def stage_key(
    stage: Stage,
    config: JobConfig,
    digests: Mapping[str, str | None],
    stages: Mapping[str, Stage],
) -> dict[str, Any]:
    """What ``stage``'s output depends on: its config sections, the digests of its inputs
    and the keys of the stages it reads. Two jobs with equal keys produce the same files, so
    a derived job reuses its parent's output of the stage (the worker compares their hashes).
    """
    return {
        "stage": stage.name,
        "config": {path: _plain(_section(config, path)) for path in stage.config},
        "inputs": {name: digests.get(name) for name in stage.inputs},
        "after": {n: stage_key(stages[n], config, digests, stages) for n in stage.needs},
    }


def _section(config: JobConfig, path: str) -> Any:
    value: Any = config
    for name in path.split("."):
        value = getattr(value, name)
    return value


def _plain(value: Any) -> Any:
    return asdict(value) if is_dataclass(value) and not isinstance(value, type) else value
