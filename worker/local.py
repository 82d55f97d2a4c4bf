"""The embedded worker of ``dcseg serve`` when no broker is configured.

It polls the job store for ``queued`` jobs (the store is the queue) and runs them with the same
:func:`worker.execute.execute_job` as the Celery task, one at a time. By default it lives in a
child process started with ``spawn`` (CUDA and torch never load in the API process, and a
crashing job cannot take the API down); ``mode="thread"`` runs it in the API process (tests).

On shutdown the current job is interrupted between iterations and left ``running``; the next
``dcseg serve`` requeues it at startup and it resumes after its last finished stage.
"""

from __future__ import annotations

import logging
import multiprocessing
import threading
from multiprocessing.process import BaseProcess
from typing import Any, Literal

from service.settings import Settings
from service.store import Store
from worker.execute import execute_job

logger = logging.getLogger(__name__)

STOP_TIMEOUT_S = 10.0


def run_local_worker(settings: Settings, stop: Any) -> None:
    """Run queued jobs until ``stop`` (a threading or multiprocessing Event) is set."""
    store = Store.from_settings(settings)
    try:
        while not stop.is_set():
            job_id = store.next_queued()
            if job_id is None:
                stop.wait(settings.poll_interval_s)
                continue
            status = execute_job(job_id, store, settings, interrupt=stop.is_set)
            logger.info("job %s: %s", job_id, status)
    except Exception:
        logger.exception("embedded worker crashed")
        raise
    finally:
        store.close()


class EmbeddedWorker:
    """Starts and stops :func:`run_local_worker` in a child process or a thread."""

    def __init__(self, settings: Settings, mode: Literal["process", "thread"] = "process") -> None:
        self.settings = settings
        self.mode = mode
        self._thread: threading.Thread | None = None
        self._process: BaseProcess | None = None
        self._stop: Any = None

    def start(self) -> None:
        if self.mode == "thread":
            self._stop = threading.Event()
            self._thread = threading.Thread(
                target=run_local_worker, args=(self.settings, self._stop), name="dcseg-worker"
            )
            self._thread.start()
        else:
            context = multiprocessing.get_context("spawn")
            self._stop = context.Event()
            self._process = context.Process(
                target=run_local_worker, args=(self.settings, self._stop), name="dcseg-worker"
            )
            self._process.start()
        logger.info("embedded worker started (%s)", self.mode)

    def alive(self) -> bool:
        runner = self._thread or self._process
        return runner is not None and runner.is_alive()

    def ensure_running(self) -> None:
        """Restart the worker if it died (its job is requeued by the lease sweep)."""
        if self._stop is not None and not self._stop.is_set() and not self.alive():
            logger.warning("embedded worker died; restarting it")
            self._thread = self._process = None
            self.start()

    def stop(self) -> None:
        if self._stop is None:
            return
        self._stop.set()
        if self._thread is not None:
            self._thread.join(STOP_TIMEOUT_S)
        if self._process is not None:
            self._process.join(STOP_TIMEOUT_S)
            if self._process.is_alive():
                logger.warning(
                    "embedded worker still busy after %.0f s; terminating", STOP_TIMEOUT_S
                )
                self._process.terminate()
                self._process.join(STOP_TIMEOUT_S)
        self._stop = None
