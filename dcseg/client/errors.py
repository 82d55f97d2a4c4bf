"""What the client raises, and the exit code each means for the CLI verbs."""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import httpx

__all__ = ["ApiError", "ClientError", "JobFailed", "NetworkError", "checked", "unreachable"]


class ClientError(RuntimeError):
    """Anything the client could not do; ``str(error)`` is one line for a human."""


class ApiError(ClientError):
    """The API answered with a problem (RFC 9457); ``problem`` holds its body.

    The message names the status, the problem's title and its detail, e.g.
    ``HTTP 404 Not Found: no job 'x'``.
    """

    def __init__(self, status: int, problem: dict[str, Any]) -> None:
        self.status = status
        self.problem = problem
        title = str(problem.get("title") or "").strip()
        detail = str(problem.get("detail") or "").strip()
        text = f"{title}: {detail}" if title and detail and title != detail else detail or title
        super().__init__(f"HTTP {status} {text or 'error'}")


class NetworkError(ClientError):
    """The service could not be reached (or kept failing with 5xx/429) after every retry."""


class JobFailed(ClientError):
    """A job ended ``failed`` or ``canceled``; ``job`` holds its last representation."""

    def __init__(self, job: dict[str, Any]) -> None:
        self.job = job
        super().__init__(f"job {job['id']} {job['status']}: {reason(job)}")


def reason(job: dict[str, Any]) -> str:
    """A failed or canceled job's reason on one line: its error (type and detail), else the
    stage it was canceled in, else its last message."""
    error = job.get("error")
    progress = job.get("progress") or {}
    if isinstance(error, dict):
        kind, detail = error.get("type"), error.get("detail") or error.get("message")
        text = f"{kind}: {detail}" if kind and detail else detail or kind or str(error)
    elif error:
        text = str(error)
    elif job.get("status") == "canceled":
        stage = job.get("stage") or progress.get("stage")
        text = f"canceled on request during {stage}" if stage else "canceled on request"
    else:
        text = job.get("message") or progress.get("message") or "no reason given"
    return " ".join(str(text).split())


def checked(response: httpx.Response) -> dict[str, Any]:
    """The JSON body of a (read) answer; ApiError with its problem when its status >= 400."""
    if response.status_code >= 400:
        try:
            problem = response.json()
        except ValueError:
            problem = {"title": response.reason_phrase, "detail": response.text.strip()}
        if not isinstance(problem, dict):
            problem = {"detail": str(problem)}
        raise ApiError(response.status_code, problem)
    body: dict[str, Any] = response.json()
    return body


def unreachable(
    url: object, method: str, error: Exception, attempt: int, started: float
) -> NetworkError:
    """The error of a request given up after ``attempt`` tries since ``started`` (monotonic)."""
    elapsed = time.monotonic() - started
    reason = str(error) or type(error).__name__
    return NetworkError(
        f"{method} {url} failed: {reason} (gave up after {attempt} tries in {elapsed:.1f} s)"
    )
