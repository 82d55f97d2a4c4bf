"""How the API hands a job to workers: by task name over Celery, or through the store.

The API never imports worker code that imports torch: :class:`CeleryQueue` sends the task by
name (``send_task``), and in embedded mode the queued row in the job store *is* the queue.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Protocol

from jobstore.contract import TASK_RUN_JOB, celery_config

if TYPE_CHECKING:
    from celery import Celery  # type: ignore[import-untyped]

    from jobstore.settings import Settings

logger = logging.getLogger(__name__)


def marker_key(queue: str) -> str:
    """The Redis key whose absence tells the API that the broker lost its data."""
    return f"_dcseg.intact.{queue}"


class JobQueue(Protocol):
    """Where the API puts job ids for workers to pick up."""

    def enqueue(self, job_id: str) -> None: ...

    def ping(self) -> None:
        """Raise unless the queue is reachable."""
        ...

    def lost_messages(self) -> bool:
        """Whether the queue lost its messages since :meth:`mark_intact` was last called (the
        caller then sends every queued job again)."""
        ...

    def mark_intact(self) -> None:
        """Record that every queued job has been sent to the queue."""
        ...


class StoreQueue:
    """Embedded mode: the job's ``queued`` row is the queue; the local worker polls for it."""

    def enqueue(self, job_id: str) -> None:
        logger.debug("job %s waits for the embedded worker", job_id)

    def ping(self) -> None:
        return None

    def lost_messages(self) -> bool:
        return False

    def mark_intact(self) -> None:
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

    def lost_messages(self) -> bool:
        """True when the marker key :meth:`mark_intact` set is gone: Redis restarted without
        persistence, was flushed or failed over to an empty replica, and took the queued
        messages with it. Brokers other than Redis answer False."""
        return bool(self._redis(lambda client: not client.exists(marker_key(self.queue))))

    def mark_intact(self) -> None:
        self._redis(lambda client: client.set(marker_key(self.queue), "1"))

    def _redis(self, call: Callable[[Any], Any]) -> Any:
        """``call(redis_client)`` on the broker's Redis; False for other brokers."""
        with self.app.connection_for_write() as conn:
            conn.ensure_connection(max_retries=1, timeout=2)
            client = getattr(conn.default_channel, "client", None)
            return False if client is None else call(client)


def make_queue(settings: Settings) -> JobQueue:
    return CeleryQueue(settings) if settings.broker_url else StoreQueue()
