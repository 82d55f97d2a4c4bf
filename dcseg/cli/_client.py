"""What the client verbs (submit, status, wait, download) share: exit codes and one-line
error messages instead of tracebacks."""

from __future__ import annotations

import sys

OK, FAILED, USAGE, UNREACHABLE, NOT_FOUND, TIMED_OUT = 0, 1, 2, 3, 4, 5
"""Exit codes: 0 done; 1 the job failed or was canceled, or the service refused the request
(4xx other than below, a failed export); 2 bad arguments; 3 the service was unreachable or
kept answering 5xx/429 after the retries; 4 not found, or not allowed (401/403/404);
5 not finished within ``--timeout``."""


def exit_code(error: BaseException) -> int:
    """The exit code of a client error (see the module's codes)."""
    from dcseg.client import ApiError, JobFailed, NetworkError

    if isinstance(error, NetworkError):
        return UNREACHABLE
    if isinstance(error, ApiError):
        if error.status in (401, 403, 404, 410):
            return NOT_FOUND
        return UNREACHABLE if error.status >= 500 or error.status == 429 else FAILED
    if isinstance(error, TimeoutError):
        return TIMED_OUT
    if isinstance(error, JobFailed):
        return FAILED
    return FAILED


def report(verb: str, error: BaseException) -> int:
    """Write ``dcseg VERB: message`` (and a problem's per-field errors) to stderr; the code."""
    from dcseg.client import ApiError

    sys.stderr.write(f"dcseg {verb}: {error}\n")
    if isinstance(error, ApiError):
        for item in error.problem.get("errors", []) or []:
            if isinstance(item, dict):
                sys.stderr.write(f"  - {item.get('path')}: {item.get('reason')}\n")
    return exit_code(error)
