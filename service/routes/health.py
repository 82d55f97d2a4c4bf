"""``/healthz`` (the process is up) and ``/readyz`` (store, storage and queue reachable)."""

from __future__ import annotations

import logging
import tempfile

from fastapi import APIRouter, Request
from fastapi.responses import JSONResponse

from service.deps import StateDep
from service.problems import problem_response, problem_responses
from service.schemas import Health

logger = logging.getLogger(__name__)

router = APIRouter(tags=["health"])


@router.get("/healthz", response_model=Health)
def healthz() -> Health:
    """The process answers."""
    return Health(status="ok")


@router.get("/readyz", response_model=Health, responses=problem_responses(503))
def readyz(request: Request, state: StateDep) -> JSONResponse:
    """Ready to take jobs: the database answers, storage is writable, the broker answers."""
    checks: dict[str, str] = {}
    try:
        state.store.ping()
        checks["database"] = "ok"
    except Exception as error:
        checks["database"] = f"error: {type(error).__name__}"
    try:
        with tempfile.TemporaryFile(dir=state.settings.storage_dir):
            pass
        checks["storage"] = "ok"
    except OSError as error:
        checks["storage"] = f"error: {type(error).__name__}"
    if state.settings.broker_url:
        try:
            state.queue.ping()
            checks["broker"] = "ok"
        except Exception as error:
            checks["broker"] = f"error: {type(error).__name__}"
    failed = sorted(k for k, v in checks.items() if v != "ok")
    if failed:
        logger.warning("not ready: %s", checks)
        detail = "unavailable: " + ", ".join(failed)
        return problem_response(
            request, 503, detail, slug="not-ready", extensions={"checks": checks}
        )
    return JSONResponse(Health(status="ok", checks=checks).model_dump())
