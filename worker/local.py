"""The embedded worker of ``dcseg serve`` when no broker is configured.

It polls the job store for ``queued`` jobs (the store is the queue) and runs them with the same
:func:`worker.execute.execute_job` as the Celery task, one at a time. By default it lives in a
child process started with ``spawn`` (CUDA and torch never load in the API process, and a
crashing job cannot take the API down); ``mode="thread"`` runs it in the API process (tests).

On shutdown the current job is interrupted at its next progress report and left ``running``;
the next ``dcseg serve`` requeues it at startup and it resumes after its last finished stage.
Stopping is bounded by ``DCSEG_SHUTDOWN_GRACE_S``: the child is asked to stop with SIGTERM
(no shared lock or semaphore, so a child that already died, for instance from a Ctrl-C or a
SIGTERM sent to the whole process group, cannot block the API's shutdown), then killed. A job
the stopped worker still held gets its attempt back (a shutdown is not a crash).
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import signal
import threading
import time
from collections.abc import Callable, Sequence
from multiprocessing.process import BaseProcess
from types import FrameType
from typing import Any, Literal

from jobstore.settings import Settings
from jobstore.store import Store
from worker.execute import execute_job, worker_id_prefix
from worker.stage import Stage

logger = logging.getLogger(__name__)

KILL_WAIT_S = 5.0
"""How long to wait for a killed child to be reaped."""

EXIT_STUCK_STAGE = 70
"""Exit status of a worker process that killed itself because a stage was stuck."""

StagesFactory = Callable[[], Sequence[Stage]]
"""Makes the stages of one job (a module-level function, so a spawned child can import it)."""


def run_local_worker(
    settings: Settings,
    stop: Any,
    *,
    stages: StagesFactory | None = None,
    kill: Callable[[], None] | None = None,
) -> None:
    """Run queued jobs until ``stop`` (a ``threading.Event``) is set.

    ``stages`` makes each job's stages (default :func:`worker.stages.default_stages`);
    ``kill`` ends the process when a stage is stuck past its time limit (None in thread mode,
    where the stuck stage is abandoned).
    """
    store = Store.from_settings(settings)
    try:
        while not stop.is_set():
            job_id = store.next_queued()
            if job_id is None:
                stop.wait(settings.poll_interval_s)
                continue
            job_stages = stages() if stages is not None else None
            status = execute_job(
                job_id, store, settings, stages=job_stages, interrupt=stop.is_set, kill=kill
            )
            logger.info("job %s: %s", job_id, status)
    except Exception:
        logger.exception("embedded worker crashed")
        raise
    finally:
        store.close()


def kill_this_process() -> None:
    """End the worker process at once (a stage is stuck; its job was already failed)."""
    logging.shutdown()
    os._exit(EXIT_STUCK_STAGE)


def run_worker_process(settings: Settings, stages: StagesFactory | None = None) -> None:
    """The child process: SIGTERM or SIGINT interrupts the running job at its next progress
    report (it stays ``running`` and resumes at the next start), then the process exits."""
    stop = threading.Event()

    def on_signal(signum: int, frame: FrameType | None) -> None:
        stop.set()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    run_local_worker(settings, stop, stages=stages, kill=kill_this_process)


class EmbeddedWorker:
    """Starts and stops :func:`run_local_worker` in a child process or a thread."""

    def __init__(
        self,
        settings: Settings,
        mode: Literal["process", "thread"] = "process",
        stages: StagesFactory | None = None,
    ) -> None:
        self.settings = settings
        self.mode = mode
        self.stages = stages
        self._thread: threading.Thread | None = None
        self._process: BaseProcess | None = None
        self._stop: threading.Event | None = None
        self._running = False

    def start(self) -> None:
        if self.mode == "thread":
            self._stop = threading.Event()
            self._thread = threading.Thread(
                target=run_local_worker,
                args=(self.settings, self._stop),
                kwargs={"stages": self.stages},
                name="dcseg-worker",
                daemon=True,  # a stage stuck past the shutdown grace must not block exit
            )
            self._thread.start()
        else:
            context = multiprocessing.get_context("spawn")
            self._process = context.Process(
                target=run_worker_process, args=(self.settings, self.stages), name="dcseg-worker"
            )
            self._process.start()
        self._running = True
        logger.info("embedded worker started (%s)", self.mode)

    def alive(self) -> bool:
        runner = self._thread or self._process
        return runner is not None and runner.is_alive()

    def ensure_running(self) -> None:
        """Restart the worker if it died (its job is requeued by the lease sweep)."""
        if self._running and not self.alive():
            logger.warning("embedded worker died; restarting it")
            self._thread = self._process = None
            self.start()

    def stop(self, deadline: float | None = None) -> None:
        """Interrupt the running job and stop by ``deadline`` (``time.monotonic()``; default
        ``shutdown_grace_s`` from now), killing the child past it (plus reaping, at most
        ``KILL_WAIT_S``). The job the worker still held, if any, then gets its attempt back:
        a shutdown is not a crash, however the worker ended."""
        if not self._running:
            return
        self._running = False
        if deadline is None:
            deadline = time.monotonic() + self.settings.shutdown_grace_s
        held = self._owner_prefix()
        if self._thread is not None and self._stop is not None:
            self._stop.set()
            self._thread.join(_remaining(deadline))
            if self._thread.is_alive():
                logger.warning("embedded worker thread still busy at the deadline; abandoned")
        if self._process is not None:
            self._stop_process(self._process, deadline)
        if held is not None:
            self._release_attempts(held)

    def _owner_prefix(self) -> str | None:
        """What the worker ids of the running worker start with (None: not started)."""
        if self._thread is not None and self._thread.ident is not None:
            return f"{worker_id_prefix(os.getpid())}:{self._thread.ident}"
        if self._process is not None and self._process.pid is not None:
            return worker_id_prefix(self._process.pid)
        return None

    def _release_attempts(self, owner: str) -> None:
        """Give back the attempt of any job ``owner`` still holds (a child killed mid-stage;
        one that stopped by itself already gave its job up, so nothing is released twice)."""
        try:
            store = Store.from_settings(self.settings)
        except Exception:
            logger.warning("could not open the store to release attempts", exc_info=True)
            return
        try:
            released = store.release_attempts_of(owner)
        except Exception:  # the job then counts one attempt more; never block the shutdown
            logger.warning("could not release the attempts of %s", owner, exc_info=True)
        else:
            if released:
                logger.info("stopped worker's job(s) %s: attempt given back", released)
        finally:
            store.close()

    @staticmethod
    def _stop_process(process: BaseProcess, deadline: float) -> None:
        if process.is_alive():
            process.terminate()  # SIGTERM: the child interrupts its job at the next report
            process.join(_remaining(deadline))
        if process.is_alive():
            logger.warning("embedded worker still busy at the shutdown deadline; killing it")
            process.kill()
            process.join(KILL_WAIT_S)


def _remaining(deadline: float) -> float:
    return max(0.0, deadline - time.monotonic())
