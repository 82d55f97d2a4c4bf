"""The I/O-free parts of :class:`dcseg.client.Client` and :class:`dcseg.client.AsyncClient`:
request bodies and headers, URLs, polling and retry decisions, download bookkeeping. Each
client keeps only its transport calls, so the two cannot drift apart."""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from dcseg.client.errors import JobFailed, checked, unreachable
from dcseg.client.events import Cursor, ServerEvent
from dcseg.client.files import ARCHIVE_TYPES
from dcseg.client.retry import RetryPolicy, never_sent, retry_after

if TYPE_CHECKING:
    import httpx

__all__ = [
    "TERMINAL",
    "EventHandler",
    "Tries",
    "auth_headers",
    "export_url",
    "finished",
    "job_body",
    "key_headers",
    "offers_stream",
    "poll_delay",
    "range_request",
    "stream_headers",
    "stream_step",
    "transport_wait",
    "upload_headers",
    "waited",
]

TERMINAL = frozenset({"succeeded", "failed", "canceled"})
"""Job statuses that never change again."""

EventHandler = Callable[[ServerEvent], None]


def auth_headers(api_key: str | None) -> dict[str, str]:
    """The headers every request carries: the bearer key, when the service has keys."""
    return {"Authorization": f"Bearer {api_key}"} if api_key else {}


def key_headers(idempotency_key: str | None) -> dict[str, str]:
    """``Idempotency-Key`` when given (it makes a POST safe to send again)."""
    return {"Idempotency-Key": idempotency_key} if idempotency_key else {}


def upload_headers(path: Path, idempotency_key: str | None, expected: str) -> dict[str, str]:
    """An upload's headers from the archive's suffix; ValueError naming ``expected`` when
    the suffix is no archive's."""
    content_type = ARCHIVE_TYPES.get(path.suffix.lower())
    if content_type is None:
        raise ValueError(f"{path}: expected {expected}")
    return {"Content-Type": content_type} | key_headers(idempotency_key)


def job_body(
    upload_id: str | None, preset: str, options: dict[str, Any] | None, parent_job_id: str | None
) -> dict[str, Any]:
    """The JSON of ``POST /v1/jobs`` (absent ids left out)."""
    body: dict[str, Any] = {"preset": preset, "options": options or {}}
    if upload_id is not None:
        body["upload_id"] = upload_id
    if parent_job_id is not None:
        body["parent_job_id"] = parent_job_id
    return body


def export_url(job_id: str, fmt: str, instance: int | None) -> str:
    """The export of the scene, or of object ``instance``, in ``fmt``."""
    base = f"/v1/jobs/{job_id}"
    where = base if instance is None else f"{base}/instances/{instance}"
    return f"{where}/exports/{fmt}"


def stream_headers(cursor: Cursor) -> dict[str, str]:
    """The event stream's request headers, resuming after the last event seen."""
    return {"Last-Event-ID": str(cursor.last), "Accept": "text/event-stream"}


def offers_stream(response: httpx.Response) -> bool:
    """Whether the answer to the events request is the event stream (else: poll the job)."""
    kind = response.headers.get("content-type", "")
    return response.status_code == 200 and kind.startswith("text/event-stream")


def stream_step(
    event: ServerEvent, cursor: Cursor, on_event: EventHandler | None, deadline: float
) -> bool | None:
    """Take one streamed event, handing it on when it is new: True when it is the
    ``completed`` one, False when ``deadline`` (monotonic) has passed, None to read on."""
    if cursor.take(event) and on_event is not None:
        on_event(event)
    if event.type == "completed":
        return True
    if time.monotonic() >= deadline:
        return False
    return None


def finished(job: dict[str, Any]) -> dict[str, Any]:
    """The job when it succeeded; JobFailed when it failed or was canceled."""
    if job["status"] != "succeeded":
        raise JobFailed(job)
    return job


def waited(
    retry: RetryPolicy, attempt: int, started: float, header: str | None = None
) -> float | None:
    """The policy's wait after try ``attempt`` of a request first tried at ``started``
    (``time.monotonic()``), honouring a ``Retry-After`` header; None to give up."""
    return retry.delay(attempt, time.monotonic() - started, retry_after(header))


def transport_wait(
    retry: RetryPolicy, retried: bool, error: Exception, attempt: int, started: float
) -> float | None:
    """The wait after a transport error: retried requests, and any that was never sent,
    wait under the policy; None to give up."""
    return waited(retry, attempt, started) if retried or never_sent(error) else None


def poll_delay(response: httpx.Response, poll: float | None) -> float:
    """Seconds until the next poll: ``poll`` when given, else the ``Retry-After``, else 2."""
    delay = poll if poll is not None else retry_after(response.headers.get("Retry-After"))
    return 2.0 if delay is None else delay


def range_request(item: dict[str, Any], partial: Path) -> tuple[int, dict[str, str]] | None:
    """Where a download of ``item`` into ``partial`` continues: the bytes already there and
    the ``Range`` headers asking for the rest; None when the file is complete. A partial
    longer than the item is deleted (it was of another file)."""
    have = partial.stat().st_size if partial.is_file() else 0
    size = item.get("size")
    if size is not None and have > size:
        partial.unlink()
        have = 0
    if size is not None and have == size:
        return None
    headers = {"Range": f"bytes={have}-", "If-Range": f'"{item["sha256"]}"'} if have else {}
    return have, headers


class Tries:
    """The tries of one request, download or event stream under a :class:`RetryPolicy`:
    counts them since a start and decides each wait, so the clients only send and sleep.

    Args:
        method, where: name the request in the NetworkError raised when giving up.
    """

    def __init__(self, retry: RetryPolicy, method: str = "GET", where: object = None) -> None:
        self.retry, self.method, self.where = retry, method, where
        self.restart()

    def restart(self) -> None:
        """Count from now again (a stream that delivered events made progress)."""
        self.started, self.attempt = time.monotonic(), 0

    def failed(self, header: str | None = None) -> float | None:
        """The wait after one more failed try, honouring a ``Retry-After`` header; None to
        give up."""
        self.attempt += 1
        return waited(self.retry, self.attempt, self.started, header)

    def dropped(self, error: Exception, retried: bool = True) -> float:
        """The wait after a transport error; raises the NetworkError when giving up. A
        request not ``retried`` is tried again only when it was never sent."""
        self.attempt += 1
        wait = transport_wait(self.retry, retried, error, self.attempt, self.started)
        if wait is None:
            raise unreachable(self.where, self.method, error, self.attempt, self.started) from error
        return wait

    def answered(self, response: httpx.Response, retried: bool) -> float | None:
        """The wait before sending a ``retried`` request again after ``response`` (a status
        worth retrying); None to keep the response."""
        if not retried or response.status_code not in self.retry.statuses:
            return None
        return self.failed(response.headers.get("Retry-After"))

    def refused(self, response: httpx.Response) -> float:
        """The wait after a download's (read) answer worth retrying; raises its ApiError when
        giving up."""
        wait = self.failed(response.headers.get("Retry-After"))
        if wait is None:
            checked(response)
        return wait or 0.0
