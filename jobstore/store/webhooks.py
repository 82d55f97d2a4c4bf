"""The webhook outbox: deliveries claimed under a lease, each attempt recorded.

A delivery row is written by the transaction that ends its job (:mod:`jobstore.store.events`).
The API's dispatcher (``service.webhooks``) claims due rows: each claim locks the rows
(``FOR UPDATE SKIP LOCKED`` on PostgreSQL; SQLite's ``BEGIN IMMEDIATE`` serialises writers)
and sets a lease from the database's clock, so two API processes never send the same row at
once, and a dispatcher that dies mid-send leaves a row another one takes once its lease ends.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime, timedelta

from sqlalchemy import ColumnElement, select

from jobstore.models import WebhookAttempt, WebhookDelivery
from jobstore.store.engine import StoreBase


@dataclass(frozen=True)
class DeliveryClaim:
    """A delivery a dispatcher holds: send it to ``url`` as attempt number ``attempt``."""

    id: int
    job_id: str
    url: str
    attempt: int


@dataclass(frozen=True)
class AttemptOutcome:
    """What one POST of a delivery got: a status code, or an error (connection, timeout)."""

    status_code: int | None
    error: str | None

    @property
    def ok(self) -> bool:
        return self.status_code is not None and 200 <= self.status_code < 300


def _due(now: datetime) -> ColumnElement[bool]:
    """Pending, its next attempt time reached, and no live lease."""
    free = WebhookDelivery.lease_until.is_(None) | (WebhookDelivery.lease_until <= now)
    return (WebhookDelivery.state == "pending") & (WebhookDelivery.next_attempt_at <= now) & free


class WebhooksMixin(StoreBase):
    """Claiming due deliveries, recording attempts, reading a job's deliveries."""

    def webhooks_due(self) -> bool:
        """Whether some delivery is due (a read: an idle dispatcher takes no write lock)."""
        with self.session(write=False) as s:
            query = select(WebhookDelivery.id).where(_due(self._now(s))).limit(1)
            return s.scalar(query) is not None

    def claim_webhook_deliveries(
        self, owner: str, lease: timedelta, limit: int = 10
    ) -> list[DeliveryClaim]:
        """Lease up to ``limit`` due deliveries to ``owner`` for ``lease``, oldest first."""
        with self.session() as s:
            now = self._now(s)
            query = (
                select(WebhookDelivery)
                .where(_due(now))
                .order_by(WebhookDelivery.next_attempt_at, WebhookDelivery.id)
                .limit(limit)
                .with_for_update(skip_locked=True)
            )
            rows = list(s.scalars(query))
            for row in rows:
                row.lease_owner, row.lease_until = owner, now + lease
            return [DeliveryClaim(r.id, r.job_id, r.url, r.attempts + 1) for r in rows]

    def record_webhook_attempt(
        self,
        claim: DeliveryClaim,
        owner: str,
        outcome: AttemptOutcome,
        *,
        max_attempts: int,
        retry_in: timedelta,
    ) -> str | None:
        """Record one attempt and release the lease: ``delivered`` on a 2xx answer, ``failed``
        after ``max_attempts``, else due again in ``retry_in``. Returns the delivery's state,
        or None when ``owner`` no longer holds it (its lease ended and another took it)."""
        with self.session() as s:
            row = s.get(WebhookDelivery, claim.id, with_for_update=True)
            if row is None or row.lease_owner != owner or row.state != "pending":
                return None
            now = self._now(s)
            row.attempts = claim.attempt
            s.add(
                WebhookAttempt(
                    delivery_id=row.id,
                    attempt=claim.attempt,
                    attempted_at=now,
                    status_code=outcome.status_code,
                    error=outcome.error,
                )
            )
            if outcome.ok or claim.attempt >= max_attempts:
                row.state = "delivered" if outcome.ok else "failed"
                row.completed_at = now
            else:
                row.next_attempt_at = now + retry_in
            row.lease_owner, row.lease_until = None, None
            return row.state

    def webhook_deliveries(self, job_id: str) -> list[tuple[WebhookDelivery, list[WebhookAttempt]]]:
        """The job's deliveries, oldest first, each with its attempts in order."""
        with self.session(write=False) as s:
            query = (
                select(WebhookDelivery)
                .where(WebhookDelivery.job_id == job_id)
                .order_by(WebhookDelivery.id)
            )
            deliveries = list(s.scalars(query))
            ids = [d.id for d in deliveries]
            attempts = list(
                s.scalars(
                    select(WebhookAttempt)
                    .where(WebhookAttempt.delivery_id.in_(ids))
                    .order_by(WebhookAttempt.delivery_id, WebhookAttempt.attempt)
                )
            )
        return [(d, [a for a in attempts if a.delivery_id == d.id]) for d in deliveries]
