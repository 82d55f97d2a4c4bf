"""``/healthz`` (the process is up) and ``/readyz`` (store, storage and queue reachable)."""

from __future__ import annotations

import logging

import anyio
import anyio.to_thread
from fastapi import APIRouter, Request
from fastapi.responses import JSONResponse

from service.deps import AppState, get_state
from service.problems import problem_response, problem_responses
from service.schemas import Health

logger = logging.getLogger(__name__)

router = APIRouter(tags=["health"])


_CHECK_THREADS = 2
"""Threads of the readiness checks, apart from the threadpool the sync routes use."""


@router.get("/healthz", response_model=Health, operation_id="getHealth")
async def healthz() -> Health:
    """The process answers (on the event loop: never waits for a thread)."""
    return Health(status="ok")


def _checks(state: AppState) -> dict[str, str]:
    checks: dict[str, str] = {}
    try:
        state.store.ping()
        checks["database"] = "ok"
    except Exception as error:
        checks["database"] = f"error: {type(error).__name__}"
    try:
        state.storage.check()
        checks["storage"] = "ok"
    except Exception as error:
        checks["storage"] = f"error: {type(error).__name__}"
    if state.settings.broker_url:
        try:
            state.queue.ping()
            checks["broker"] = "ok"
        except Exception as error:
            checks["broker"] = f"error: {type(error).__name__}"
    return checks


def _limiter(request: Request) -> anyio.CapacityLimiter:
    """The app's readiness-check threads, made on first use inside the event loop."""
    limiter: anyio.CapacityLimiter | None = getattr(request.app.state, "health_limiter", None)
    if limiter is None:
        limiter = anyio.CapacityLimiter(_CHECK_THREADS)
        request.app.state.health_limiter = limiter
    return limiter


@router.get(
    "/readyz", response_model=Health, responses=problem_responses(503), operation_id="getReadiness"
)
async def readyz(request: Request) -> JSONResponse:
    """Ready to take jobs: the database answers, storage is writable, the broker answers.
    The checks run on threads of their own, so a busy threadpool does not delay them."""
    state = get_state(request)  # not a dependency: sync dependencies take a pool thread
    checks = await anyio.to_thread.run_sync(_checks, state, limiter=_limiter(request))
    failed = sorted(k for k, v in checks.items() if v != "ok")
    if failed:
        logger.warning("not ready: %s", checks)
        detail = "unavailable: " + ", ".join(failed)
        return problem_response(
            request, 503, detail, slug="not-ready", extensions={"checks": checks}
        )
    return JSONResponse(Health(status="ok", checks=checks).model_dump())
