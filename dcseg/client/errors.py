"""What the client raises, and the exit code each means for the CLI verbs."""

from __future__ import annotations

from typing import Any

__all__ = ["ApiError", "ClientError", "JobFailed", "NetworkError"]


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
    """A failed or canceled job's reason on one line (its error's message, or its message)."""
    error = job.get("error")
    if isinstance(error, dict):
        kind, detail = error.get("type"), error.get("detail") or error.get("message")
        text = f"{kind}: {detail}" if kind and detail else detail or kind or str(error)
    else:
        text = error or job.get("message") or "no reason given"
    return " ".join(str(text).split())
