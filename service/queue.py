"""How the API hands a job to workers: by task name over Celery, or through the store.

The API never imports worker code that imports torch: :class:`CeleryQueue` sends the task by
name (``send_task``), and in embedded mode the queued row in the job store *is* the queue.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Protocol

from worker.contract import TASK_RUN_JOB, celery_config

if TYPE_CHECKING:
    from celery import Celery  # type: ignore[import-untyped]

    from service.settings import Settings

logger = logging.getLogger(__name__)


class JobQueue(Protocol):
    """Where the API puts job ids for workers to pick up."""

    def enqueue(self, job_id: str) -> None: ...

    def ping(self) -> None:
        """Raise unless the queue is reachable."""
        ...


class StoreQueue:
    """Embedded mode: the job's ``queued`` row is the queue; the local worker polls for it."""

    def enqueue(self, job_id: str) -> None:
        logger.debug("job %s waits for the embedded worker", job_id)

    def ping(self) -> None:
        return None


class CeleryQueue:
    """Sends ``dcseg.run_job`` by name to the broker (Redis)."""

    def __init__(self, settings: Settings) -> None:
        from celery import Celery

        assert settings.broker_url is not None
        self.queue = settings.gpu_queue
        self.app: Celery = Celery("dcseg-api", broker=settings.broker_url, set_as_current=False)
        self.app.conf.update(
            celery_config(
                queue=settings.gpu_queue,
                visibility_timeout_s=settings.visibility_timeout_s,
                soft_time_limit_s=settings.task_soft_time_limit_s,
                time_limit_s=settings.task_time_limit_s,
            )
        )

    def enqueue(self, job_id: str) -> None:
        self.app.send_task(TASK_RUN_JOB, args=[job_id], queue=self.queue)

    def ping(self) -> None:
        with self.app.connection_for_write() as conn:
            conn.ensure_connection(max_retries=1, timeout=2)


def make_queue(settings: Settings) -> JobQueue:
    return CeleryQueue(settings) if settings.broker_url else StoreQueue()
