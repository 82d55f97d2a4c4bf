"""The FastAPI application: ``create_app(settings)``; ``app`` is the default instance.

Nothing touches the database or the disk at import time: the lifespan opens the store, checks
the schema, loads API keys, sweeps unfinished jobs, starts the webhook dispatcher
(:mod:`service.webhooks`) and the local worker it is given, if any. The API never imports
``worker``: ``dcseg serve`` (the layer above both) hands it the embedded worker
(:class:`LocalWorker`) when no broker is configured.
"""

from __future__ import annotations

import asyncio
import functools
import logging
import shutil
import time
from collections.abc import AsyncIterator, Callable, Sequence
from contextlib import asynccontextmanager
from datetime import timedelta
from pathlib import Path
from typing import Protocol

from fastapi import FastAPI

from dcseg import __version__
from jobstore.blobstore import Storage, make_storage
from jobstore.settings import Settings, get_settings
from jobstore.store import Store
from service import openapi, problems
from service.background import in_thread
from service.deps import LOCAL_TENANT, AppState, make_limiter
from service.exports import Exporter
from service.queue import JobQueue, make_queue
from service.routes import (
    artifacts,
    direct_uploads,
    events,
    exports,
    health,
    instances,
    jobs,
    uploads,
    viewer,
)
from service.uploads import remove_expired_uploads
from service.webhooks import Dispatcher

logger = logging.getLogger(__name__)

DESCRIPTION = """\
Segment posed RGB-D captures into labelled 3D Gaussians.

Upload a capture archive (`POST /v1/uploads`), submit a job (`POST /v1/jobs`), poll it
(`GET /v1/jobs/{id}`) or stream its events, then download its artifacts. Errors are RFC 9457
`application/problem+json`. Authenticate with `Authorization: Bearer <api key>`.
"""


class LocalWorker(Protocol):
    """A worker that runs jobs inside or beside the API process (embedded mode, no broker),
    started and stopped by the app's lifespan; ``worker.local.EmbeddedWorker`` is one."""

    def start(self) -> None: ...

    def ensure_running(self) -> None:
        """Start the worker again if it died."""
        ...

    def stop(self, deadline: float | None = None) -> None:
        """Stop by ``deadline`` (``time.monotonic()``)."""
        ...


LocalWorkerFactory = Callable[[Settings], LocalWorker | None]
"""Makes the app's local worker from its settings; None = no local worker with them."""


def sweep(store: Store, queue: JobQueue, settings: Settings) -> bool:
    """Pick up jobs a previous run left unfinished; False when they still need re-sending.

    Embedded mode owns every job: running ones go back to ``queued`` and the local worker
    resumes them after their last finished stage. With a broker, queued jobs and running jobs
    whose worker stopped heartbeating are sent again (a duplicate delivery is harmless: only
    one worker can claim a job); if the broker is down, the recovery sweep retries.
    """
    if settings.broker_url is None:
        requeued = store.requeue_running()
        if requeued:
            logger.info("requeued %d unfinished job(s): %s", len(requeued), requeued)
        return True
    try:
        resend_unfinished(store, queue, settings)
    except Exception:
        logger.exception("could not re-send unfinished jobs; the recovery sweep retries")
        return False
    return True


def resend_unfinished(store: Store, queue: JobQueue, settings: Settings) -> int:
    """Send every queued job (and running job with a stale lease) to the queue again, then
    mark the queue intact; returns how many were sent. Raises when the broker is down (the
    queue is then not marked, so the next sweep tries again)."""
    job_ids = store.unfinished(timedelta(seconds=3 * settings.heartbeat_s))
    for job_id in job_ids:
        queue.enqueue(job_id)
    queue.mark_intact()
    return len(job_ids)


def recover_once(store: Store, queue: JobQueue, settings: Settings, resend: bool) -> None:
    """One pass of the recovery sweep (blocking): requeue and send running jobs whose worker
    died; re-send every queued job when ``resend`` or when the broker lost its messages."""
    for job_id in store.requeue_stale(timedelta(seconds=3 * settings.heartbeat_s)):
        logger.warning("job %s lost its worker; requeued", job_id)
        queue.enqueue(job_id)
    if resend or queue.lost_messages():
        sent = resend_unfinished(store, queue, settings)
        logger.warning("the broker had lost queued messages; re-sent %d job(s)", sent)


async def recover_lost_jobs(
    store: Store,
    queue: JobQueue,
    settings: Settings,
    local: LocalWorker | None,
    resend: bool = False,
) -> None:
    """Forever: requeue running jobs whose worker died (stale heartbeat) and enqueue them;
    re-send queued jobs when the broker lost its data (Redis restarted without persistence)
    or ``resend`` (the startup sweep could not reach it); restart the embedded worker if it
    died."""
    while True:
        await asyncio.sleep(settings.sweep_interval_s)
        if local is not None:
            local.ensure_running()
        try:
            await in_thread(recover_once, store, queue, settings, resend)
            resend = False
        except Exception:
            logger.exception("recovery sweep failed; retrying")


async def shut_down(
    tasks: Sequence[asyncio.Task[None]], local: LocalWorker | None, grace_s: float
) -> None:
    """Cancel the background ``tasks`` (recovery sweep, housekeeping) and stop the embedded
    worker, side by side and to one deadline ``grace_s`` from now: the whole shutdown takes at
    most ``grace_s`` plus the worker's ``KILL_WAIT_S`` to reap a killed child. A task blocked
    in the database past the deadline (its thread cannot be interrupted) is left behind."""
    deadline = time.monotonic() + grace_s
    for task in tasks:
        task.cancel()  # first: the recovery sweep must not restart the worker being stopped
    stopping = asyncio.ensure_future(asyncio.to_thread(local.stop, deadline)) if local else None
    _, pending = await asyncio.wait(tasks, timeout=max(0.0, deadline - time.monotonic()))
    if pending:
        names = ", ".join(sorted(task.get_name() for task in pending))
        logger.warning("%s still busy after %g s; shutting down anyway", names, grace_s)
    if stopping is not None:
        await stopping  # bounded by the deadline plus KILL_WAIT_S


ABANDONED_UPLOAD_S = 24 * 3600.0
"""Temporary upload folders older than this were left by a crashed request; removed at start."""


def remove_abandoned_uploads(storage: Path) -> None:
    """Delete ``uploads/.tmp-*`` folders old enough to belong to no live request (other API
    replicas may share the storage, so recent ones are left alone)."""
    cutoff = time.time() - ABANDONED_UPLOAD_S
    for folder in (storage / "uploads").glob(".tmp-*"):
        if folder.stat().st_mtime < cutoff:
            logger.info("removing abandoned upload %s", folder.name)
            shutil.rmtree(folder, ignore_errors=True)


def housekeep_once(store: Store, settings: Settings, storage: Storage) -> None:
    """Delete expired uploads and idempotency records (blocking)."""
    remove_expired_uploads(store, settings, storage)
    store.idempotency_sweep(timedelta(seconds=settings.idempotency_ttl_s))


async def housekeep(store: Store, settings: Settings, storage: Storage) -> None:
    """Forever, every ``housekeeping_interval_s``: :func:`housekeep_once`."""
    while True:
        await asyncio.sleep(settings.housekeeping_interval_s)
        try:
            await in_thread(housekeep_once, store, settings, storage)
        except Exception:
            logger.exception("housekeeping failed; retrying")


def open_state(settings: Settings) -> AppState:
    """Open the store (creating or checking the schema), load keys, build the queue."""
    settings.storage_dir.mkdir(parents=True, exist_ok=True)
    remove_abandoned_uploads(settings.storage_dir)
    store = Store.from_settings(settings)
    store.init_schema()
    keys = settings.parsed_api_keys()
    key_hashes = store.sync_api_keys(keys)
    if not keys:
        store.ensure_tenant(LOCAL_TENANT)
        reach = "every client" if settings.allow_unauthenticated else "loopback clients only"
        logger.warning("no API keys: authentication is off (tenant %r, %s)", LOCAL_TENANT, reach)
    queue = make_queue(settings)
    storage = make_storage(settings)
    storage.setup()
    return AppState(
        settings=settings,
        store=store,
        queue=queue,
        storage=storage,
        key_hashes=key_hashes,
        limiter=make_limiter(settings, "requests", settings.rate_limit_per_minute),
        auth_limiter=make_limiter(settings, "failed-auth", settings.failed_auth_per_minute),
    )


def create_app(
    settings: Settings | None = None, *, local_worker: LocalWorkerFactory | None = None
) -> FastAPI:
    """A new app; ``settings`` defaults to the environment's (:func:`get_settings`).
    ``local_worker`` makes the worker the lifespan starts after the startup sweep and stops at
    shutdown (``dcseg serve`` passes the embedded worker's); None = the API alone."""

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        current = settings or get_settings()
        app.state.draining = asyncio.Event()  # set by events.begin_draining at shutdown
        state = open_state(current)
        app.state.dcseg = state
        app.state.exporter = Exporter(current)
        swept = sweep(state.store, state.queue, current)
        local = local_worker(current) if local_worker is not None else None
        if local is not None:
            local.start()
        recovery = asyncio.create_task(
            recover_lost_jobs(state.store, state.queue, current, local, resend=not swept),
            name="recovery sweep",
        )
        housekeeping = asyncio.create_task(
            housekeep(state.store, current, state.storage), name="housekeeping"
        )
        webhooks = asyncio.create_task(
            Dispatcher(state.store, current).run(), name="webhook dispatcher"
        )
        undo_drain = events.drain_on_signals(app)  # SIGTERM ends open event streams at once
        try:
            yield
        finally:
            app.state.exporter.close()
            await shut_down([recovery, housekeeping, webhooks], local, current.shutdown_grace_s)
            state.store.close()
            undo_drain()

    app = FastAPI(
        title="dcseg",
        version=__version__,
        description=DESCRIPTION,
        lifespan=lifespan,
    )
    problems.install(app)
    app.openapi = functools.partial(openapi.document, app)  # type: ignore[method-assign]
    for module in (
        uploads,
        direct_uploads,
        jobs,
        events,
        artifacts,
        instances,
        exports,
        health,
        viewer,
    ):
        app.include_router(module.router)
    return app


app = create_app()
