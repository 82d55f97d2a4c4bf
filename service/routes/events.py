"""``GET /v1/jobs/{id}/events``: server-sent events with ``Last-Event-ID`` replay.

Events come from the job store (``id:`` is the job's event sequence number), so a client that
reconnects with ``Last-Event-ID: n`` receives every event after ``n``. The stream ends after
the ``completed`` event, or cleanly after ``max_stream_s`` (a comment line says so; clients
reconnect with ``Last-Event-ID``); a comment line is sent every 15 s to keep proxies from
closing it. A tenant may hold ``max_streams_per_tenant`` streams per API process (429 past it).
When the server begins to shut down (:func:`begin_draining`, on the server's SIGTERM or SIGINT,
see :func:`drain_on_signals`) every open stream ends at once the same way: uvicorn waits for
open responses before it runs the app's shutdown, so a stream would otherwise hold it.
"""

from __future__ import annotations

import asyncio
import json
import signal
import threading
import time
from collections.abc import AsyncIterator, Callable
from types import FrameType
from typing import Annotated, Any

from fastapi import APIRouter, Header, Query, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import StreamingResponse
from starlette.applications import Starlette
from starlette.types import Receive, Scope, Send

from jobstore.models import Event
from service.deps import AppState, StateDep, StreamSlots, TenantDep
from service.problems import ApiProblem, problem_responses

router = APIRouter(prefix="/v1/jobs", tags=["jobs"])

KEEPALIVE_S = 15.0

JOB_EVENT_REF = "#/components/schemas/JobEvent"
"""One event of the stream (``service.schemas.JobEvent``; ``service.openapi`` adds it)."""

EVENT_STREAM = {
    "schema": {"type": "string", "description": "server-sent events, each a `JobEvent`"},
    "x-itemSchema": {"$ref": JOB_EVENT_REF},
}
"""The stream's OpenAPI media type: the body is text (so generated clients hand it over as a
string instead of failing to parse it as one JSON object) and each event is a ``JobEvent``,
named the way OpenAPI 3.2 does (``itemSchema``), as an extension in this 3.1 document."""


def draining(app: Starlette) -> asyncio.Event:
    """Set once the server begins shutting down; open event streams then end. The lifespan
    makes a new one at each start (an event belongs to one event loop)."""
    event = getattr(app.state, "draining", None)
    if not isinstance(event, asyncio.Event):
        event = app.state.draining = asyncio.Event()
    return event


def begin_draining(app: Starlette, loop: asyncio.AbstractEventLoop) -> None:
    """End ``app``'s open event streams (safe from a signal handler or another thread;
    ``loop`` is the server's event loop)."""
    loop.call_soon_threadsafe(lambda: draining(app).set())


def drain_on_signals(app: Starlette) -> Callable[[], None]:
    """Make the server's SIGTERM and SIGINT handlers (uvicorn's, installed before the app
    starts) also call :func:`begin_draining`; returns what undoes it. Does nothing outside
    the main thread (a test client) or when a signal has no Python handler."""
    if threading.current_thread() is not threading.main_thread():
        return lambda: None
    loop = asyncio.get_running_loop()
    chained: dict[int, Callable[[int, FrameType | None], Any]] = {}

    def handler(signum: int, frame: FrameType | None) -> None:
        begin_draining(app, loop)
        chained[signum](signum, frame)

    for sig in (signal.SIGTERM, signal.SIGINT):
        previous = signal.getsignal(sig)
        if callable(previous):
            chained[sig] = previous
            signal.signal(sig, handler)

    def undo() -> None:
        for sig, previous in chained.items():
            if signal.getsignal(sig) is handler:
                signal.signal(sig, previous)

    return undo


async def _stopped(stop: asyncio.Event | None, pause: float) -> bool:
    """Sleep ``pause``; True at once when ``stop`` is set."""
    if stop is None:
        await asyncio.sleep(pause)
        return False
    try:
        await asyncio.wait_for(stop.wait(), pause)
    except TimeoutError:
        return False
    return True


def format_event(event: Event) -> str:
    data = json.dumps(event.data, separators=(",", ":"))
    return f"id: {event.seq}\nevent: {event.type}\ndata: {data}\n\n"


async def stream_events(
    state: AppState, job_id: str, after: int, stop: asyncio.Event | None = None
) -> AsyncIterator[str]:
    """The events of ``job_id`` after ``after``, until ``completed``, the job's deletion,
    ``max_stream_s`` or ``stop`` (the server shuts down). While nothing happens the pause
    between polls doubles from ``poll_interval_s`` up to ``stream_poll_max_s``; the job row
    is read only with each keep-alive (to notice a deletion)."""
    settings = state.settings
    yield "retry: 2000\n\n"
    started = last_sent = time.monotonic()
    pause = settings.poll_interval_s
    longest = max(settings.poll_interval_s, settings.stream_poll_max_s)
    while True:
        events = await run_in_threadpool(state.store.events_after, job_id, after)
        for event in events:
            after = event.seq
            yield format_event(event)
            if event.type == "completed":
                return
        now = time.monotonic()
        if events:
            last_sent, pause = now, settings.poll_interval_s
        elif now - last_sent >= KEEPALIVE_S:
            if await run_in_threadpool(state.store.get_job, job_id) is None:
                return  # deleted while streaming
            yield ": keepalive\n\n"
            last_sent = now
        if now - started >= settings.max_stream_s:
            yield f": stream lifetime reached; reconnect with Last-Event-ID: {after}\n\n"
            return
        if await _stopped(stop, pause):
            yield f": server shutting down; reconnect with Last-Event-ID: {after}\n\n"
            return
        if not events:
            pause = min(2 * pause, longest)


class SlotStreamingResponse(StreamingResponse):
    """A stream that holds one of the tenant's stream slots until it ends, however it ends
    (completed, lifetime reached, client gone, cancelled)."""

    def __init__(
        self, content: AsyncIterator[str], slots: StreamSlots, tenant: str, **kwargs: Any
    ) -> None:
        super().__init__(content, **kwargs)
        self._slots, self._tenant = slots, tenant

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        try:
            await super().__call__(scope, receive, send)
        finally:
            self._slots.release(self._tenant)


@router.get(
    "/{job_id}/events",
    response_class=StreamingResponse,
    responses={
        200: {
            "description": "event stream: each event as `JobEvent` describes it (`event:` "
            "status, progress, log or completed; `id:` its number; `data:` its JSON)",
            "content": {"text/event-stream": EVENT_STREAM},
        },
        **problem_responses(401, 404, 422, 429),
    },
    operation_id="streamJobEvents",
)
async def job_events(
    job_id: str,
    request: Request,
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
    cap = state.settings.max_streams_per_tenant
    if not state.streams.acquire(tenant, cap):
        raise ApiProblem(
            429,
            f"{cap} event streams are already open for this tenant "
            "(DCSEG_MAX_STREAMS_PER_TENANT); close one, or poll GET /v1/jobs/{id}",
            slug="too-many-streams",
            headers={"Retry-After": str(state.settings.retry_after_s)},
            job_id=job_id,
        )
    return SlotStreamingResponse(
        stream_events(state, job_id, start, draining(request.app)),
        state.streams,
        tenant,
        media_type="text/event-stream",
        headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"},
    )
