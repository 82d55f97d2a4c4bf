"""The Celery app: ``celery -A worker.celery_app worker -Q gpu --concurrency 1``.

The task is a thin adapter over :func:`worker.execute.execute_job`. Settings (see
``worker.contract.celery_config``):

* ``task_acks_late`` + ``task_reject_on_worker_lost``: a job whose worker dies is redelivered;
  ``execute_job`` resumes after its last finished stage.
* ``worker_prefetch_multiplier = 1``: a worker reserves one job at a time.
* Redis ``visibility_timeout`` = ``DCSEG_VISIBILITY_TIMEOUT_S`` (default 12 h): longer than the
  longest queue wait plus run time, or Redis would hand a long job to a second worker. A job
  lost with its worker is also re-sent by the API's startup sweep once its heartbeat is stale.
* Soft/hard task time limits (``DCSEG_TASK_SOFT_TIME_LIMIT_S``, ``DCSEG_TASK_TIME_LIMIT_S``;
  the hard limit needs the prefork pool); per-stage limits are checked between iterations.
* Route ``dcseg.run_job`` to the ``gpu`` queue; run one worker process per GPU.

CUDA is never initialised here: torch loads inside the task, in the worker child process.
"""

from __future__ import annotations

import logging
from functools import lru_cache

from celery import Celery  # type: ignore[import-untyped]

from service.settings import get_settings
from service.store import Store
from worker.contract import TASK_RUN_JOB, celery_config
from worker.execute import execute_job

logger = logging.getLogger(__name__)


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


@app.task(name=TASK_RUN_JOB)  # type: ignore[untyped-decorator]
def run_job(job_id: str) -> str:
    """Run one job; the job store, not Celery's result backend, records the outcome."""
    return execute_job(job_id, _store(), get_settings())
