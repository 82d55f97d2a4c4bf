"""When the client tries a request again: which failures, how long it waits, when it gives up.

Shared by :class:`dcseg.client.Client` and :class:`dcseg.client.AsyncClient`: the policy only
computes delays; each client sleeps in its own way.
"""

from __future__ import annotations

import random
from dataclasses import dataclass, field
from datetime import UTC, datetime
from email.utils import parsedate_to_datetime

__all__ = [
    "IDEMPOTENT_METHODS",
    "NEVER",
    "RETRY_STATUSES",
    "RetryPolicy",
    "never_sent",
    "replayable",
    "retry_after",
]

IDEMPOTENT_METHODS = frozenset({"GET", "HEAD", "PUT", "DELETE", "OPTIONS"})
"""Methods safe to send again (RFC 9110 9.2.2); a POST is when it carries an Idempotency-Key."""

RETRY_STATUSES = frozenset({429, 502, 503, 504})
"""Answers that say "try later": rate limited, or a proxy/the service temporarily unavailable."""


@dataclass(frozen=True)
class RetryPolicy:
    """Bounded retries with full-jitter exponential backoff (AWS's "Exponential Backoff And
    Jitter"): attempt ``n`` waits a uniform random time in ``[0, min(max_backoff_s,
    backoff_s * 2**n)]``, or the server's ``Retry-After`` when it sends one."""

    attempts: int = 6
    """Tries per request, the first included (1 = never retry)."""
    total_s: float = 120.0
    """Give up once this many seconds have passed since the first try (or a wait would pass
    it); a ``Retry-After`` longer than what is left is not waited for."""
    backoff_s: float = 0.5
    """Upper bound of the first wait; doubles with each try."""
    max_backoff_s: float = 20.0
    """Upper bound of any computed wait (not of a server's ``Retry-After``)."""
    statuses: frozenset[int] = field(default=RETRY_STATUSES)
    """Statuses retried on idempotent requests."""

    def __post_init__(self) -> None:
        if self.attempts < 1:
            raise ValueError(f"attempts must be at least 1, not {self.attempts}")
        if self.total_s < 0 or self.backoff_s < 0 or self.max_backoff_s < 0:
            raise ValueError("total_s, backoff_s and max_backoff_s must not be negative")

    def delay(
        self, attempt: int, elapsed: float, server_delay: float | None = None
    ) -> float | None:
        """Seconds to wait before try ``attempt + 1`` (``attempt`` counts from 1, the try that
        just failed), or None to give up. ``elapsed`` is the time since the first try."""
        if attempt >= self.attempts:
            return None
        if server_delay is not None:
            wait = max(0.0, server_delay)
        else:
            wait = random.uniform(0.0, min(self.max_backoff_s, self.backoff_s * 2 ** (attempt - 1)))
        if elapsed + wait > self.total_s:
            return None
        return wait


NEVER = RetryPolicy(attempts=1)
"""No retries: every failure is final."""


def retry_after(value: str | None, now: datetime | None = None) -> float | None:
    """The seconds a ``Retry-After`` header asks for (delay-seconds or an HTTP-date, RFC 9110
    10.2.3); None when absent or unreadable, 0 for a date already past."""
    if value is None or not value.strip():
        return None
    text = value.strip()
    if text.isdigit():
        return float(text)
    try:
        when = parsedate_to_datetime(text)
    except (TypeError, ValueError):
        return None
    if when.tzinfo is None:
        when = when.replace(tzinfo=UTC)
    return max(0.0, (when - (now or datetime.now(UTC))).total_seconds())


def replayable(method: str, headers: dict[str, str] | None) -> bool:
    """Whether a request may be sent again after a failure that may have reached the server:
    an idempotent method, or a POST with an ``Idempotency-Key``."""
    return method in IDEMPOTENT_METHODS or "Idempotency-Key" in (headers or {})


def never_sent(error: Exception) -> bool:
    """Whether the request failed before its connection opened (safe to send again)."""
    import httpx

    return isinstance(error, httpx.ConnectError | httpx.ConnectTimeout)
