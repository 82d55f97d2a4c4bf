"""RFC 9457 problem details for every 4xx/5xx answer, validation errors and 404 routes included."""

from __future__ import annotations

import logging
from http import HTTPStatus
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import BaseModel, ConfigDict
from sqlalchemy.exc import OperationalError
from starlette.exceptions import HTTPException as StarletteHTTPException

logger = logging.getLogger(__name__)

PROBLEM_JSON = "application/problem+json"
TYPE_PREFIX = "urn:dcseg:problem:"
"""Problem ``type`` URIs are ``urn:dcseg:problem:<slug>``; plain HTTP errors use about:blank."""


class ApiProblem(Exception):
    """Raise anywhere in a request to answer with a problem+json body."""

    def __init__(
        self,
        status: int,
        detail: str,
        *,
        slug: str | None = None,
        title: str | None = None,
        headers: dict[str, str] | None = None,
        **extensions: Any,
    ) -> None:
        super().__init__(detail)
        self.status = status
        self.detail = detail
        self.slug = slug
        self.title = title or HTTPStatus(status).phrase
        self.headers = headers or {}
        self.extensions = extensions


def problem_response(
    request: Request,
    status: int,
    detail: str,
    *,
    slug: str | None = None,
    title: str | None = None,
    headers: dict[str, str] | None = None,
    extensions: dict[str, Any] | None = None,
) -> JSONResponse:
    body: dict[str, Any] = {
        "type": f"{TYPE_PREFIX}{slug}" if slug else "about:blank",
        "title": title or HTTPStatus(status).phrase,
        "status": status,
        "detail": detail,
        "instance": request.url.path,
    }
    body.update(extensions or {})
    return JSONResponse(body, status_code=status, headers=headers, media_type=PROBLEM_JSON)


def _location(loc: tuple[Any, ...] | list[Any]) -> str:
    return ".".join(str(part) for part in loc)


async def _api_problem(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, ApiProblem)
    return problem_response(
        request,
        exc.status,
        exc.detail,
        slug=exc.slug,
        title=exc.title,
        headers=exc.headers,
        extensions=exc.extensions,
    )


async def _http_error(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, StarletteHTTPException)
    detail = exc.detail if isinstance(exc.detail, str) else HTTPStatus(exc.status_code).phrase
    if exc.status_code == 404 and detail == "Not Found":
        detail = f"no resource at {request.url.path}"
    return problem_response(request, exc.status_code, detail, headers=dict(exc.headers or {}))


async def _validation_error(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, RequestValidationError)
    errors = list(exc.errors())
    if any(e.get("type") == "json_invalid" for e in errors):
        first = next(e for e in errors if e.get("type") == "json_invalid")
        reason = str(first.get("ctx", {}).get("error", "invalid JSON"))
        return problem_response(
            request,
            400,
            f"the request body is not valid JSON ({reason})",
            slug="malformed-json",
            title="Malformed JSON",
            extensions={"errors": [{"path": "body", "reason": reason}]},
        )
    items = [{"path": _location(e.get("loc", ())), "reason": str(e.get("msg", ""))} for e in errors]
    return problem_response(
        request,
        422,
        f"{len(items)} invalid field(s): "
        + "; ".join(f"{i['path']}: {i['reason']}" for i in items),
        slug="validation-error",
        title="Request validation failed",
        extensions={"errors": items},
    )


async def _database_unavailable(request: Request, exc: Exception) -> JSONResponse:
    """The database refused or dropped the connection (restarting, failing over, overloaded):
    503 with ``Retry-After``, which clients retry, instead of a 500."""
    logger.warning("database unavailable on %s %s: %s", request.method, request.url.path, exc)
    state = getattr(request.app.state, "dcseg", None)
    wait = state.settings.retry_after_s if state is not None else 2
    return problem_response(
        request,
        503,
        "the database is unavailable; the request was not completed, retry after Retry-After",
        slug="database-unavailable",
        title="Database unavailable",
        headers={"Retry-After": str(wait)},
    )


async def _server_error(request: Request, exc: Exception) -> JSONResponse:
    logger.exception("unhandled error on %s %s", request.method, request.url.path, exc_info=exc)
    return problem_response(request, 500, "internal error; the request was not completed")


def install(app: FastAPI) -> None:
    """Register the handlers that turn every error into problem+json."""
    app.add_exception_handler(ApiProblem, _api_problem)
    app.add_exception_handler(StarletteHTTPException, _http_error)
    app.add_exception_handler(RequestValidationError, _validation_error)
    app.add_exception_handler(OperationalError, _database_unavailable)
    app.add_exception_handler(Exception, _server_error)


class ProblemError(BaseModel):
    """One refused field or file of a problem: where (``body.options.affinity.margin``, an
    archive member) and why."""

    model_config = ConfigDict(extra="allow")

    path: str
    reason: str


class Problem(BaseModel):
    """An RFC 9457 problem body, as every 4xx/5xx answer carries it (``application/problem+json``).

    ``type`` is ``urn:dcseg:problem:<slug>`` (``about:blank`` for plain HTTP errors); the
    optional members are extensions some problems add; clients must tolerate others."""

    model_config = ConfigDict(extra="allow", title="Problem")

    type: str
    title: str
    status: int
    detail: str
    instance: str
    """The request's path."""
    errors: list[ProblemError] | None = None
    """Each refused field or file (validation errors, refused uploads and exports)."""
    job_id: str | None = None
    """The job the problem concerns."""
    limit: int | None = None
    """The byte limit a too large upload passed (413)."""
    quota: int | None = None
    """The tenant's storage quota in bytes (507 ``storage-quota-exceeded``)."""
    used: int | None = None
    """The bytes the tenant stores (507 ``storage-quota-exceeded``)."""
    free: int | None = None
    """The storage volume's free bytes (507 ``insufficient-storage``)."""
    checks: dict[str, str] | None = None
    """``/readyz``: each dependency's state (503 ``not-ready``)."""


PROBLEM_REF = "#/components/schemas/Problem"
"""Where the OpenAPI document describes :class:`Problem` (``service.openapi`` puts it there)."""

PROBLEM_CONTENT: dict[str, Any] = {"content": {PROBLEM_JSON: {"schema": {"$ref": PROBLEM_REF}}}}
"""OpenAPI content of a problem response: a reference to the one ``Problem`` component."""


def problem_responses(*codes: int) -> dict[int | str, dict[str, Any]]:
    """``responses=`` entries documenting problem bodies for ``codes``."""
    return {code: {"description": HTTPStatus(code).phrase, **PROBLEM_CONTENT} for code in codes}
