"""``GET /v1/jobs/{id}/events``: server-sent events with ``Last-Event-ID`` replay.

Events come from the job store (``id:`` is the job's event sequence number), so a client that
reconnects with ``Last-Event-ID: n`` receives every event after ``n``. The stream ends after
the ``completed`` event; a comment line is sent every 15 s to keep proxies from closing it.
"""

from __future__ import annotations

import asyncio
import json
import time
from collections.abc import AsyncIterator
from typing import Annotated

from fastapi import APIRouter, Header, Query
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import StreamingResponse

from service.deps import AppState, StateDep, TenantDep
from service.models import Event
from service.problems import ApiProblem, problem_responses

router = APIRouter(prefix="/v1/jobs", tags=["jobs"])

KEEPALIVE_S = 15.0


def format_event(event: Event) -> str:
    data = json.dumps(event.data, separators=(",", ":"))
    return f"id: {event.seq}\nevent: {event.type}\ndata: {data}\n\n"


async def stream_events(state: AppState, job_id: str, after: int) -> AsyncIterator[str]:
    yield "retry: 2000\n\n"
    last_sent = time.monotonic()
    while True:
        events = await run_in_threadpool(state.store.events_after, job_id, after)
        for event in events:
            after = event.seq
            yield format_event(event)
            if event.type == "completed":
                return
        if not events:
            job = await run_in_threadpool(state.store.get_job, job_id)
            if job is None:  # deleted while streaming
                return
            if time.monotonic() - last_sent > KEEPALIVE_S:
                yield ": keepalive\n\n"
                last_sent = time.monotonic()
            await asyncio.sleep(state.settings.poll_interval_s)
        else:
            last_sent = time.monotonic()


@router.get(
    "/{job_id}/events",
    response_class=StreamingResponse,
    responses={
        200: {"content": {"text/event-stream": {}}, "description": "event stream"},
        **problem_responses(401, 404, 422),
    },
)
async def job_events(
    job_id: str,
    state: StateDep,
    tenant: TenantDep,
    last_event_id: Annotated[int, Header(alias="Last-Event-ID", ge=0)] = 0,
    after: Annotated[int | None, Query(ge=0, description="same as Last-Event-ID")] = None,
) -> StreamingResponse:
    """Events ``status``, ``progress``, ``log`` and ``completed`` (the last one)."""
    start = after if after is not None else last_event_id
    job = await run_in_threadpool(state.store.get_job, job_id, tenant)
    if job is None:
        raise ApiProblem(404, f"no job {job_id!r}", slug="not-found", job_id=job_id)
    return StreamingResponse(
        stream_events(state, job_id, start),
        media_type="text/event-stream",
        headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"},
    )
