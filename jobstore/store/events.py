"""A job's events: every status change appends its event in the transaction that makes it.

Event numbers (``seq``) increase by one per job and never repeat or skip, because the job's
row is locked while its event is appended (see :mod:`jobstore.store.engine`). The transaction
that ends a job with a ``callback_url`` also writes its webhook's outbox row
(:mod:`jobstore.store.webhooks`).
"""

from __future__ import annotations

from typing import Any

from sqlalchemy import select
from sqlalchemy.orm import Session

from jobstore.models import Event, Job, WebhookDelivery
from jobstore.store.engine import StoreBase


class EventsMixin(StoreBase):
    """Reading a job's events, and the status changes that append them."""

    def events_after(self, job_id: str, seq: int, limit: int = 500) -> list[Event]:
        query = (
            select(Event)
            .where(Event.job_id == job_id, Event.seq > seq)
            .order_by(Event.seq)
            .limit(limit)
        )
        with self.session(write=False) as s:
            return list(s.scalars(query))

    def _set(self, s: Session, job: Job, **changes: Any) -> None:
        for name, value in changes.items():
            setattr(job, name, value)
        job.updated_at = self._now(s)
        self._event(s, job, "status", {"status": job.status, "message": job.message})

    def _finish(
        self, s: Session, job: Job, status: str, error: dict[str, Any] | None, message: str
    ) -> None:
        job.status, job.error, job.message = status, error, message or None
        job.completed_at = job.updated_at = self._now(s)
        if status == "succeeded":
            job.progress = 1.0
        data = {"status": status, "message": job.message, "error": error}
        self._event(s, job, "completed", data)
        if job.callback_url:  # the webhook's outbox row, in the transaction that ends the job
            now = job.completed_at
            s.add(
                WebhookDelivery(
                    job_id=job.id,
                    url=job.callback_url,
                    job_status=status,
                    state="pending",
                    attempts=0,
                    next_attempt_at=now,
                    created_at=now,
                )
            )

    def _event(self, s: Session, job: Job, type_: str, data: dict[str, Any]) -> None:
        job.event_seq += 1
        now = self._now(s)
        s.add(Event(job_id=job.id, seq=job.event_seq, type=type_, data=data, created_at=now))
