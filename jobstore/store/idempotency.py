"""``Idempotency-Key`` records: the first response to a keyed POST, per tenant.

The HTTP side (headers, replays) is ``service.idempotency``; this keeps the records and decides,
in one transaction per call, whether a request is new, a replay, in flight or a mismatch.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import timedelta
from typing import Any, Literal

from sqlalchemy import select
from sqlalchemy.exc import IntegrityError

from jobstore.models import IdempotencyKey, utcnow
from jobstore.store.engine import StoreBase

IDEMPOTENCY_ABANDONED = timedelta(hours=1)
"""An in-flight idempotency record older than this is taken over (its request died); the API
passes :attr:`Settings.idempotency_in_flight_s`."""


@dataclass(frozen=True)
class IdempotencyOutcome:
    """What to do with a request carrying an ``Idempotency-Key``."""

    kind: Literal["new", "replay", "in_flight", "mismatch"]
    status_code: int | None = None
    response: dict[str, Any] | None = None


class IdempotencyMixin(StoreBase):
    """Reserving a key, keeping its response, releasing it, sweeping old records."""

    def idempotency_begin(
        self,
        tenant: str,
        key: str,
        request_hash: str,
        ttl: timedelta | None = None,
        in_flight: timedelta = IDEMPOTENCY_ABANDONED,
    ) -> IdempotencyOutcome:
        """Reserve ``key`` for this request, or say how to answer a repeated one.

        A record older than ``ttl`` is forgotten: the key counts as new. A request without an
        answer yet blocks the key for ``in_flight``, then counts as abandoned.
        """
        try:
            with self.session() as s:
                s.add(IdempotencyKey(tenant_id=tenant, key=key, request_hash=request_hash))
            return IdempotencyOutcome("new")
        except IntegrityError:
            pass
        with self.session() as s:
            row = s.get(IdempotencyKey, (tenant, key), with_for_update=True)
            if row is None:  # released in between: try again once
                s.add(IdempotencyKey(tenant_id=tenant, key=key, request_hash=request_hash))
                return IdempotencyOutcome("new")
            if ttl is not None and utcnow() - row.created_at >= ttl:
                row.request_hash, row.status_code, row.response = request_hash, None, None
                row.created_at = utcnow()
                return IdempotencyOutcome("new")
            if row.request_hash != request_hash:
                return IdempotencyOutcome("mismatch")
            if row.status_code is None:
                if utcnow() - row.created_at < in_flight:
                    return IdempotencyOutcome("in_flight")
                row.created_at = utcnow()
                return IdempotencyOutcome("new")
            return IdempotencyOutcome("replay", row.status_code, row.response)

    def idempotency_finish(
        self, tenant: str, key: str, status_code: int, response: dict[str, Any]
    ) -> None:
        with self.session() as s:
            row = s.get(IdempotencyKey, (tenant, key), with_for_update=True)
            if row is not None:
                row.status_code = status_code
                row.response = response

    def idempotency_release(self, tenant: str, key: str) -> None:
        """Forget an in-flight key whose request failed, so the client may retry."""
        with self.session() as s:
            row = s.get(IdempotencyKey, (tenant, key))
            if row is not None and row.status_code is None:
                s.delete(row)

    def idempotency_sweep(self, older_than: timedelta) -> int:
        """Delete idempotency records older than ``older_than``; returns how many."""
        cutoff = utcnow() - older_than
        with self.session() as s:
            rows = list(s.scalars(select(IdempotencyKey).where(IdempotencyKey.created_at < cutoff)))
            for row in rows:
                s.delete(row)
        return len(rows)
