"""The Celery app: ``celery -A worker.celery_app worker -Q gpu --concurrency 1``.

The task is a thin adapter over :func:`worker.execute.execute_job`. Settings (see
``jobstore.contract.celery_config``):

* ``task_acks_late`` + ``task_reject_on_worker_lost``: a job whose worker dies is redelivered;
  ``execute_job`` resumes after its last finished stage.
* ``worker_prefetch_multiplier = 1``: a worker reserves one job at a time.
* Redis ``visibility_timeout`` = ``DCSEG_VISIBILITY_TIMEOUT_S`` (default 12 h): longer than the
  longest queue wait plus run time, or Redis would hand a long job to a second worker. A job
  lost with its worker is also re-sent by the API's startup sweep once its heartbeat is stale.
* Soft/hard task time limits (``DCSEG_TASK_SOFT_TIME_LIMIT_S``, ``DCSEG_TASK_TIME_LIMIT_S``;
  the hard limit needs the prefork pool). Per-stage limits (``DCSEG_STAGE_TIME_LIMIT_S``) are
  checked at each progress report; a stage that reports none for ``DCSEG_STAGE_KILL_GRACE_S``
  past its limit fails the job and, in a prefork pool child, the child is killed (the pool
  starts a new one; the redelivered message finds the job failed and is dropped).
* Route ``dcseg.run_job`` to the ``gpu`` queue; run one worker process per GPU.
* Warm shutdown (SIGTERM, ``docker compose stop``): the running job stops at its next progress
  report, keeps its finished stages, gives up its lease and is rejected back to the queue
  (not acknowledged as done); the next worker resumes it. In the prefork pool the main
  process forwards the shutdown to its pool children with ``INTERRUPT_SIGNAL``.

CUDA is never initialised here: torch loads inside the task, in the worker child process.
"""

from __future__ import annotations

import logging
import os
import signal
import threading
from functools import lru_cache
from types import FrameType
from typing import Any

from celery import Celery  # type: ignore[import-untyped]
from celery.exceptions import Reject  # type: ignore[import-untyped]
from celery.signals import (  # type: ignore[import-untyped]
    worker_process_init,
    worker_shutting_down,
)

from jobstore.contract import TASK_RUN_JOB, celery_config
from jobstore.settings import get_settings
from jobstore.store import Store
from worker.execute import execute_job
from worker.local import StagesFactory, kill_this_process

logger = logging.getLogger(__name__)

INTERRUPT_SIGNAL = signal.SIGUSR2
"""Sent by the main process to its prefork pool children when the worker shuts down (Celery
keeps SIGTERM for killing children at a cold shutdown or a hard time limit)."""

stages_factory: StagesFactory | None = None
"""The stages each job runs (None: :func:`worker.stages.default_stages`); tests set it."""

_shutting_down = threading.Event()
"""Set when this worker shuts down: the running job stops at its next progress report."""

_kill: Any = None
"""How a stuck stage ends this process: set in prefork pool children only (killing the solo
or threads pool's process would stop the whole worker)."""


def make_celery() -> Celery:
    settings = get_settings()
    celery = Celery("dcseg", broker=settings.broker_url or "redis://127.0.0.1:6379/0")
    celery.conf.update(
        celery_config(
            queue=settings.gpu_queue,
            visibility_timeout_s=settings.visibility_timeout_s,
            soft_time_limit_s=settings.task_soft_time_limit_s,
            time_limit_s=settings.task_time_limit_s,
        )
    )
    return celery


app = make_celery()


@lru_cache
def _store() -> Store:
    """One store per worker process, opened on first use (after the pool forked)."""
    store = Store.from_settings(get_settings())
    store.init_schema()
    return store


def _interrupt(signum: int, frame: FrameType | None) -> None:
    _shutting_down.set()


@worker_process_init.connect  # type: ignore[untyped-decorator]
def _init_pool_child(**kwargs: Any) -> None:
    """In a prefork pool child: shut down on ``INTERRUPT_SIGNAL``; a stuck stage may kill it."""
    global _kill
    _kill = kill_this_process
    signal.signal(INTERRUPT_SIGNAL, _interrupt)


@worker_shutting_down.connect  # type: ignore[untyped-decorator]
def _on_shutdown(**kwargs: Any) -> None:
    """The main process got SIGTERM/SIGINT/SIGQUIT: interrupt the running job (solo and
    threads pools run it in this process; prefork children get ``INTERRUPT_SIGNAL``)."""
    _shutting_down.set()
    from billiard.process import active_children  # type: ignore[import-untyped]

    for child in active_children():
        if child.pid is not None:
            try:
                os.kill(child.pid, INTERRUPT_SIGNAL)
            except ProcessLookupError:
                pass


@app.task(name=TASK_RUN_JOB)  # type: ignore[untyped-decorator]
def run_job(job_id: str) -> str:
    """Run one job; the job store, not Celery's result backend, records the outcome.

    An interrupted job (worker shutdown) is rejected back to the queue, not acknowledged.
    """
    stages = stages_factory() if stages_factory is not None else None
    status = execute_job(
        job_id,
        _store(),
        get_settings(),
        stages=stages,
        interrupt=_shutting_down.is_set,
        kill=_kill,
    )
    if status == "interrupted":
        raise Reject(f"job {job_id} interrupted by worker shutdown; requeued", requeue=True)
    return status
