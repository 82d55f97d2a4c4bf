"""The job store: every read and write of job records, uploads, events and API keys.

Shared by the API and the workers (no torch, no HTTP). Each mutation of a job locks its row
(``SELECT ... FOR UPDATE`` on PostgreSQL; SQLite write transactions start with
``BEGIN IMMEDIATE``, reads with a plain deferred ``BEGIN``) and appends its event in the same
transaction, so event numbers never repeat or skip. Lease, start, update and completion
times come from the database's clock, never from a worker's or API host's clock (only
``created_at`` is the API host's).
"""

from __future__ import annotations

import hashlib
import logging
import uuid
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from typing import TYPE_CHECKING, Any, Literal

from sqlalchemy import Connection, create_engine, event, func, insert, inspect, select, text
from sqlalchemy.engine import Engine
from sqlalchemy.exc import IntegrityError, OperationalError, ProgrammingError
from sqlalchemy.orm import Session, sessionmaker
from sqlalchemy.pool import ConnectionPoolEntry

from jobstore.contract import ACTIVE, TERMINAL
from jobstore.models import (
    SCHEMA_VERSION,
    ApiKey,
    Base,
    Event,
    IdempotencyKey,
    Job,
    SchemaVersion,
    Tenant,
    Upload,
    utcnow,
)

if TYPE_CHECKING:
    from jobstore.settings import Settings

logger = logging.getLogger(__name__)


def _add_upload_stored_bytes(conn: Connection) -> None:
    """v2: ``uploads.stored_bytes`` (bytes of the extracted upload; NULL = use ``size``)."""
    conn.exec_driver_sql("ALTER TABLE uploads ADD COLUMN stored_bytes BIGINT")


MIGRATIONS: dict[int, Callable[[Connection], None]] = {2: _add_upload_stored_bytes}
"""``MIGRATIONS[v]`` upgrades a version ``v - 1`` schema to version ``v``."""

SYNC_ATTEMPTS = 3
"""Tries of :meth:`Store.sync_api_keys` when replicas starting together collide."""

IDEMPOTENCY_ABANDONED = timedelta(hours=1)
"""An in-flight idempotency record older than this is taken over (its request died); the API
passes :attr:`Settings.idempotency_in_flight_s`."""

READ_ONLY = "dcseg_read_only"
"""Execution option of read sessions: SQLite opens them with a deferred ``BEGIN``."""


Lease = Literal["ok", "cancel", "lost"]
"""What a worker learns when it reports: go on, stop for a cancel, or stop (job taken over)."""


class SchemaError(RuntimeError):
    """The database schema cannot be used by this code."""


class UploadInUse(Exception):
    """An upload still referenced by jobs cannot be deleted (answered with 409)."""


class TooManyJobs(Exception):
    """The tenant already has its cap of unfinished jobs (answered with 429)."""

    def __init__(self, active: int, limit: int) -> None:
        super().__init__(f"{active} unfinished jobs; the limit is {limit}")
        self.active = active
        self.limit = limit


class Conflict(Exception):
    """The job's state forbids the operation (answered with 409)."""

    def __init__(self, job: Job, detail: str) -> None:
        super().__init__(detail)
        self.job = job
        self.detail = detail


def hash_key(key: str) -> str:
    """How API keys are stored: random tokens, so a plain SHA-256 is enough."""
    return hashlib.sha256(key.encode()).hexdigest()


def new_id() -> str:
    return str(uuid.uuid4())


@dataclass(frozen=True)
class IdempotencyOutcome:
    """What to do with a request carrying an ``Idempotency-Key``."""

    kind: Literal["new", "replay", "in_flight", "mismatch"]
    status_code: int | None = None
    response: dict[str, Any] | None = None


@dataclass(frozen=True)
class Cursor:
    """Position after the last job of a page (jobs are listed newest first)."""

    created_at: datetime
    job_id: str


def _sqlite_connect(dbapi_conn: Any, busy_timeout_s: float) -> None:
    dbapi_conn.isolation_level = None  # we issue BEGIN ourselves (below)
    cursor = dbapi_conn.cursor()
    cursor.execute("PRAGMA journal_mode=WAL")
    cursor.execute("PRAGMA foreign_keys=ON")
    cursor.execute(f"PRAGMA busy_timeout={round(busy_timeout_s * 1000)}")
    cursor.close()


def _sqlite_begin(conn: Connection) -> None:
    # Writes: IMMEDIATE takes the write lock up front, so no "database is locked" on lock
    # upgrades. Reads: a deferred BEGIN takes no write lock (WAL readers never wait for writers).
    read_only = conn.get_execution_options().get(READ_ONLY, False)
    conn.exec_driver_sql("BEGIN" if read_only else "BEGIN IMMEDIATE")


def make_engine(url: str, busy_timeout_s: float = 10.0) -> Engine:
    """An engine for ``url``; SQLite gets WAL, foreign keys, immediate write transactions and a
    ``busy_timeout_s`` wait for another writer's lock."""
    if url.startswith("sqlite"):
        engine = create_engine(
            url, connect_args={"check_same_thread": False, "timeout": busy_timeout_s}
        )

        def on_connect(dbapi_conn: Any, _record: ConnectionPoolEntry) -> None:
            _sqlite_connect(dbapi_conn, busy_timeout_s)

        event.listen(engine, "connect", on_connect)
        event.listen(engine, "begin", _sqlite_begin)
        return engine
    return create_engine(url, pool_pre_ping=True)


class Store:
    """Job records in a SQL database (SQLite file or PostgreSQL)."""

    def __init__(self, url: str, *, busy_timeout_s: float = 10.0, max_attempts: int = 3) -> None:
        """``busy_timeout_s``: SQLite's wait for a write lock; ``max_attempts``: claims of a job
        before it fails (see :class:`jobstore.settings.Settings`, whose defaults these match)."""
        self.url = url
        self.max_attempts = max_attempts
        self.engine = make_engine(url, busy_timeout_s)
        self._sessions = sessionmaker(self.engine, expire_on_commit=False)
        reads = self.engine.execution_options(**{READ_ONLY: True})
        self._reads = sessionmaker(reads, expire_on_commit=False)

    @classmethod
    def from_settings(cls, settings: Settings) -> Store:
        """The store of ``settings.db_url`` with the settings' lock timeout and attempts cap."""
        return cls(
            settings.db_url,
            busy_timeout_s=settings.busy_timeout_s,
            max_attempts=settings.max_attempts,
        )

    @contextmanager
    def session(self, write: bool = True) -> Iterator[Session]:
        """One transaction: committed on success, rolled back on error. ``write=False`` for
        reads: on SQLite they then take no write lock (and never wait for one)."""
        with (self._sessions if write else self._reads).begin() as session:
            yield session

    def close(self) -> None:
        self.engine.dispose()

    # ----- schema -----
    def init_schema(self) -> int:
        """Create the tables, or check and migrate an existing schema; returns its version."""
        try:
            return self._init_schema()
        except (IntegrityError, OperationalError, ProgrammingError):
            # another process created the schema at the same moment: check what it made
            logger.info("schema creation raced with another process; checking again")
            return self._init_schema()

    def _init_schema(self) -> int:
        with self.engine.begin() as conn:
            if not inspect(conn).has_table(SchemaVersion.__tablename__):
                Base.metadata.create_all(conn)
                conn.execute(insert(SchemaVersion).values(version=SCHEMA_VERSION))
                logger.info("created job store schema v%d", SCHEMA_VERSION)
                return SCHEMA_VERSION
            current = conn.execute(select(func.max(SchemaVersion.version))).scalar()
            if current is None:
                raise SchemaError("schema_version table is empty; cannot tell the schema version")
            if current > SCHEMA_VERSION:
                raise SchemaError(
                    f"database schema v{current} is newer than this code (v{SCHEMA_VERSION}); "
                    "upgrade dcseg"
                )
            for version in range(current + 1, SCHEMA_VERSION + 1):
                MIGRATIONS[version](conn)
                conn.execute(insert(SchemaVersion).values(version=version))
                logger.info("migrated job store schema to v%d", version)
            return SCHEMA_VERSION

    def ping(self) -> None:
        """Raise unless the database answers (a read: no SQLite write lock)."""
        with self.engine.execution_options(**{READ_ONLY: True}).connect() as conn:
            conn.exec_driver_sql("SELECT 1")

    # ----- tenants and keys -----
    def sync_api_keys(self, keys: dict[str, str]) -> dict[str, str]:
        """Make the stored keys exactly ``keys`` (``{key: tenant}``); returns ``{hash: tenant}``.

        API replicas starting together race to insert the same rows: a unique violation means
        another replica got there first, and the sync runs again (it then finds the rows).
        """
        for attempt in range(SYNC_ATTEMPTS):
            try:
                return self._sync_api_keys(keys)
            except IntegrityError:
                if attempt == SYNC_ATTEMPTS - 1:
                    raise
                logger.info("API keys were being synced by another replica; syncing again")
        raise AssertionError("unreachable")  # pragma: no cover

    def _sync_api_keys(self, keys: dict[str, str]) -> dict[str, str]:
        wanted = {hash_key(k): t for k, t in keys.items()}
        with self.session() as s:
            for tenant in sorted(set(wanted.values())):
                self._ensure_tenant(s, tenant)
            s.flush()
            for row in s.scalars(select(ApiKey)):
                if wanted.get(row.key_hash) != row.tenant_id:
                    s.delete(row)
            s.flush()
            stored = set(s.scalars(select(ApiKey.key_hash)))
            s.add_all(ApiKey(key_hash=h, tenant_id=t) for h, t in wanted.items() if h not in stored)
        return wanted

    def ensure_tenant(self, tenant: str) -> None:
        try:
            with self.session() as s:
                self._ensure_tenant(s, tenant)
        except IntegrityError:  # another replica inserted it meanwhile
            with self.session(write=False) as s:
                if s.get(Tenant, tenant) is None:
                    raise

    @staticmethod
    def _ensure_tenant(s: Session, tenant: str) -> None:
        if s.get(Tenant, tenant) is None:
            s.add(Tenant(id=tenant))

    # ----- uploads -----
    def add_upload(self, upload: Upload) -> Upload:
        with self.session() as s:
            s.add(upload)
        return upload

    def get_upload(self, upload_id: str, tenant: str) -> Upload | None:
        with self.session() as s:
            upload = s.get(Upload, upload_id)
        return upload if upload is not None and upload.tenant_id == tenant else None

    def delete_upload(self, upload_id: str, tenant: str | None) -> Upload | None:
        """Delete an upload record (of ``tenant``, or of anyone when None); ``UploadInUse``
        while jobs refer to it. The row lock and the job's foreign key order this against a
        job being created for it: one of the two fails cleanly."""
        with self.session() as s:
            upload = s.get(Upload, upload_id, with_for_update=True)
            if upload is None or (tenant is not None and upload.tenant_id != tenant):
                return None
            jobs = s.scalar(select(func.count()).where(Job.upload_id == upload_id)) or 0
            if jobs:
                raise UploadInUse(f"{jobs} job(s) use this upload; delete them first")
            s.delete(upload)
        return upload

    def unused_uploads(self, created_before: datetime) -> list[str]:
        """Ids of uploads created before ``created_before`` that no job refers to."""
        used = select(Job.id).where(Job.upload_id == Upload.id).exists()
        query = select(Upload.id).where(Upload.created_at < created_before, ~used)
        with self.session() as s:
            return list(s.scalars(query.order_by(Upload.created_at)))

    def tenant_storage(self, tenant: str) -> tuple[int, list[str]]:
        """The bytes of the tenant's stored uploads and the ids of its jobs (their outputs are
        measured from their manifests)."""
        stored = func.coalesce(Upload.stored_bytes, Upload.size)
        with self.session() as s:
            used = s.scalar(select(func.sum(stored)).where(Upload.tenant_id == tenant)) or 0
            jobs = list(s.scalars(select(Job.id).where(Job.tenant_id == tenant)))
        return int(used), jobs

    # ----- jobs: API side -----
    def create_job(self, job: Job, *, max_active: int | None = None) -> Job:
        """Insert a queued job and its first event; ``TooManyJobs`` when the tenant already
        has ``max_active`` unfinished jobs.

        Count and insert share one transaction that holds the tenant's row lock (PostgreSQL;
        SQLite's ``BEGIN IMMEDIATE`` serialises all writers), so concurrent requests cannot
        both pass the check.
        """
        with self.session() as s:
            if max_active is not None:
                s.get(Tenant, job.tenant_id, with_for_update={"key_share": True})
                active = self._count_active(s, job.tenant_id)
                if active >= max_active:
                    raise TooManyJobs(active, max_active)
            s.add(job)
            s.flush()
            self._event(s, job, "status", {"status": job.status})
        return job

    def get_job(self, job_id: str, tenant: str | None = None) -> Job | None:
        """The job, or None when it does not exist or belongs to another tenant."""
        with self.session(write=False) as s:
            job = s.get(Job, job_id)
        if job is None or (tenant is not None and job.tenant_id != tenant):
            return None
        return job

    def list_jobs(
        self, tenant: str, *, status: str | None, after: Cursor | None, limit: int
    ) -> tuple[list[Job], bool]:
        """A page of the tenant's jobs, newest first, and whether more follow."""
        query = select(Job).where(Job.tenant_id == tenant)
        if status is not None:
            query = query.where(Job.status == status)
        if after is not None:
            query = query.where(
                (Job.created_at < after.created_at)
                | ((Job.created_at == after.created_at) & (Job.id < after.job_id))
            )
        query = query.order_by(Job.created_at.desc(), Job.id.desc()).limit(limit + 1)
        with self.session(write=False) as s:
            jobs = list(s.scalars(query))
        return jobs[:limit], len(jobs) > limit

    def count_active(self, tenant: str) -> int:
        with self.session(write=False) as s:
            return self._count_active(s, tenant)

    @staticmethod
    def _count_active(s: Session, tenant: str) -> int:
        query = select(func.count()).where(Job.tenant_id == tenant, Job.status.in_(ACTIVE))
        return int(s.scalar(query) or 0)

    def request_cancel(self, job_id: str, tenant: str) -> Job | None:
        """Cancel a queued job at once, or flag a running one; Conflict when terminal."""
        with self.session() as s:
            job = self._lock(s, job_id, tenant)
            if job is None:
                return None
            if job.status in TERMINAL:
                raise Conflict(job, f"job is already {job.status}")
            job.cancel_requested = True
            if job.status == "queued":
                self._finish(s, job, "canceled", None, "canceled before it started")
            elif job.status == "running":
                self._set(s, job, status="canceling", message="cancel requested")
        return job

    def delete_job(self, job_id: str, tenant: str) -> Job | None:
        """Delete a finished job's record and events; Conflict while it is unfinished."""
        with self.session() as s:
            job = self._lock(s, job_id, tenant)
            if job is None:
                return None
            if job.status not in TERMINAL:
                raise Conflict(job, f"job is {job.status}; cancel it and wait until it ends")
            for ev in s.scalars(select(Event).where(Event.job_id == job_id)):
                s.delete(ev)
            s.delete(job)
        return job

    def events_after(self, job_id: str, seq: int, limit: int = 500) -> list[Event]:
        query = (
            select(Event)
            .where(Event.job_id == job_id, Event.seq > seq)
            .order_by(Event.seq)
            .limit(limit)
        )
        with self.session(write=False) as s:
            return list(s.scalars(query))

    # ----- idempotency -----
    def idempotency_begin(
        self,
        tenant: str,
        key: str,
        request_hash: str,
        ttl: timedelta | None = None,
        in_flight: timedelta = IDEMPOTENCY_ABANDONED,
    ) -> IdempotencyOutcome:
        """Reserve ``key`` for this request, or say how to answer a repeated one.

        A record older than ``ttl`` is forgotten: the key counts as new. A request without an
        answer yet blocks the key for ``in_flight``, then counts as abandoned.
        """
        try:
            with self.session() as s:
                s.add(IdempotencyKey(tenant_id=tenant, key=key, request_hash=request_hash))
            return IdempotencyOutcome("new")
        except IntegrityError:
            pass
        with self.session() as s:
            row = s.get(IdempotencyKey, (tenant, key), with_for_update=True)
            if row is None:  # released in between: try again once
                s.add(IdempotencyKey(tenant_id=tenant, key=key, request_hash=request_hash))
                return IdempotencyOutcome("new")
            if ttl is not None and utcnow() - row.created_at >= ttl:
                row.request_hash, row.status_code, row.response = request_hash, None, None
                row.created_at = utcnow()
                return IdempotencyOutcome("new")
            if row.request_hash != request_hash:
                return IdempotencyOutcome("mismatch")
            if row.status_code is None:
                if utcnow() - row.created_at < in_flight:
                    return IdempotencyOutcome("in_flight")
                row.created_at = utcnow()
                return IdempotencyOutcome("new")
            return IdempotencyOutcome("replay", row.status_code, row.response)

    def idempotency_finish(
        self, tenant: str, key: str, status_code: int, response: dict[str, Any]
    ) -> None:
        with self.session() as s:
            row = s.get(IdempotencyKey, (tenant, key), with_for_update=True)
            if row is not None:
                row.status_code = status_code
                row.response = response

    def idempotency_release(self, tenant: str, key: str) -> None:
        """Forget an in-flight key whose request failed, so the client may retry."""
        with self.session() as s:
            row = s.get(IdempotencyKey, (tenant, key))
            if row is not None and row.status_code is None:
                s.delete(row)

    def idempotency_sweep(self, older_than: timedelta) -> int:
        """Delete idempotency records older than ``older_than``; returns how many."""
        cutoff = utcnow() - older_than
        with self.session() as s:
            rows = list(s.scalars(select(IdempotencyKey).where(IdempotencyKey.created_at < cutoff)))
            for row in rows:
                s.delete(row)
        return len(rows)

    # ----- jobs: worker side -----
    def claim_job(self, job_id: str, worker: str, stale_after: timedelta) -> Job | None:
        """Make ``worker`` the job's runner, or return None if it must not run it.

        A queued job is claimed; a running job only when its heartbeat is older than
        ``stale_after`` (its worker died and the task was redelivered); a job with a cancel
        request ends ``canceled`` here, and a job already claimed ``max_attempts`` times ends
        ``failed`` (its workers keep dying).
        """
        with self.session() as s:
            job = self._lock(s, job_id, None)
            if job is None or job.status in TERMINAL:
                return None
            now = self._now(s)
            if job.cancel_requested:
                self._finish(s, job, "canceled", None, "canceled before it resumed")
                return None
            beat = job.heartbeat_at
            if job.status == "running" and beat is not None and now - beat < stale_after:
                return None
            if self._fail_if_exhausted(s, job):
                return None
            resumed = job.status == "running"
            job.attempts += 1
            job.started_at = job.started_at or now
            self._set(
                s,
                job,
                status="running",
                worker=worker,
                heartbeat_at=now,
                message="resumed after a lost worker" if resumed else "started",
            )
        return job

    def release_attempts_of(self, worker: str) -> list[str]:
        """Runs of ``worker``, or of any worker id under it (``host:pid`` covers every
        ``host:pid:thread``), stopped for a shutdown: each job still held by one of them
        (running or canceling) gets its attempt back and is given up at once (lease expired,
        no runner), so it is released once only. Returns the released jobs' ids."""
        owners = (Job.worker == worker) | Job.worker.startswith(f"{worker}:", autoescape=True)
        query = (
            select(Job)
            .where(Job.status.in_(("running", "canceling")), owners)
            .order_by(Job.id)
            .with_for_update()
        )
        with self.session() as s:
            jobs = list(s.scalars(query))
            stale = self._now(s) - timedelta(days=1)  # stale for any heartbeat_s
            for job in jobs:
                job.attempts = max(0, job.attempts - 1)
                job.heartbeat_at, job.worker = stale, None
            return [job.id for job in jobs]

    def next_queued(self) -> str | None:
        """The oldest queued job's id (the embedded worker's queue)."""
        query = select(Job.id).where(Job.status == "queued").order_by(Job.created_at).limit(1)
        with self.session(write=False) as s:
            return s.scalar(query)

    def heartbeat(self, job_id: str, worker: str) -> Lease:
        """Refresh ``worker``'s lease on the job; says whether to go on, cancel or stop."""
        with self.session() as s:
            job = self._owned(s, job_id, worker)
            if job is None:
                return "lost"
            job.heartbeat_at = self._now(s)
            return "cancel" if job.cancel_requested else "ok"

    def report_progress(
        self,
        job_id: str,
        worker: str,
        stage: tuple[str, int, int],
        fraction: float,
        message: str,
    ) -> Lease:
        """Record progress (``stage`` = name, index, count) and emit a ``progress`` event."""
        name, index, count = stage
        with self.session() as s:
            job = self._owned(s, job_id, worker)
            if job is None:
                return "lost"
            job.stage, job.stage_index, job.stage_count = name, index, count
            job.progress = max(0.0, min(1.0, fraction))
            job.message = message
            job.heartbeat_at = job.updated_at = self._now(s)
            data = {"stage": name, "stage_index": index, "stage_count": count}
            self._event(s, job, "progress", data | {"fraction": job.progress, "message": message})
            return "cancel" if job.cancel_requested else "ok"

    def log(self, job_id: str, message: str, **data: Any) -> None:
        with self.session() as s:
            job = self._lock(s, job_id, None)
            if job is not None:
                self._event(s, job, "log", {"message": message, **data})

    def finish_job(
        self,
        job_id: str,
        status: str,
        error: dict[str, Any] | None = None,
        message: str = "",
        *,
        worker: str | None = None,
    ) -> str | None:
        """Move a job to a terminal status and emit the ``completed`` event; returns the
        status recorded, or None when nothing changed.

        A job whose cancel was acknowledged (``canceling``) ends ``canceled`` whatever its run
        reports (a failure's ``error`` is kept). With ``worker``, only while that worker still
        holds the job (a worker whose lease was taken over must not overwrite the new run's
        outcome).
        """
        with self.session() as s:
            job = self._owned(s, job_id, worker) if worker else self._lock(s, job_id, None)
            if job is None or job.status in TERMINAL:
                return None
            if job.status == "canceling" and status != "canceled":
                message = f"canceled (cancel requested; the run had ended {status})"
                status = "canceled"
            self._finish(s, job, status, error, message)
            return status

    def requeue_running(self) -> list[str]:
        """Startup sweep of the embedded mode: running jobs go back to the queue (jobs at
        ``max_attempts`` fail instead); returns the requeued ones."""
        ids: list[str] = []
        with self.session() as s:
            query = select(Job).where(Job.status.in_(("running", "canceling"))).with_for_update()
            for job in s.scalars(query):
                if job.cancel_requested:
                    self._finish(s, job, "canceled", None, "canceled while the service was down")
                elif not self._fail_if_exhausted(s, job):
                    ids.append(job.id)
                    self._set(s, job, status="queued", worker=None, message="requeued at startup")
        return ids

    def requeue_stale(self, stale_after: timedelta) -> list[str]:
        """Running jobs whose worker stopped heartbeating go back to ``queued`` (jobs at
        ``max_attempts`` fail instead); returns the requeued ones.

        Safe with several API replicas: each job row is locked, so only one requeues it.
        """
        ids: list[str] = []
        with self.session() as s:
            cutoff = self._now(s) - stale_after
            query = (
                select(Job)
                .where(Job.status.in_(("running", "canceling")), Job.heartbeat_at <= cutoff)
                .with_for_update(skip_locked=True)
            )
            for job in s.scalars(query):
                if job.cancel_requested:
                    self._finish(s, job, "canceled", None, "canceled; its worker was lost")
                elif not self._fail_if_exhausted(s, job):
                    ids.append(job.id)
                    self._set(s, job, status="queued", worker=None, message="worker lost; requeued")
        return ids

    def unfinished(self, stale_after: timedelta) -> list[str]:
        """Queued jobs and running jobs whose heartbeat is stale (the Celery-mode sweep)."""
        with self.session(write=False) as s:
            cutoff = self._now(s) - stale_after
            query = select(Job.id).where(
                (Job.status == "queued")
                | (
                    (Job.status == "running")
                    & ((Job.heartbeat_at <= cutoff) | Job.heartbeat_at.is_(None))
                )
            )
            return list(s.scalars(query.order_by(Job.created_at)))

    # ----- helpers -----
    def _owned(self, s: Session, job_id: str, worker: str) -> Job | None:
        """The job if ``worker`` holds it (running or canceling), else None."""
        job = self._lock(s, job_id, None)
        if job is None or job.worker != worker or job.status not in ("running", "canceling"):
            return None
        return job

    @staticmethod
    def _lock(s: Session, job_id: str, tenant: str | None) -> Job | None:
        job = s.get(Job, job_id, with_for_update=True)
        if job is None or (tenant is not None and job.tenant_id != tenant):
            return None
        return job

    @staticmethod
    def _now(s: Session) -> datetime:
        """The database's clock (UTC), read once per transaction: lease times and the
        staleness cutoffs computed from them never depend on a host's clock."""
        cached = s.info.get("now")
        if isinstance(cached, datetime):
            return cached
        if s.get_bind().dialect.name == "sqlite":
            # SQLite's clock as text (UTC, milliseconds); converted so that it is bound back
            # through the column type, in the same text format as every stored time.
            raw = s.scalar(text("SELECT strftime('%Y-%m-%d %H:%M:%f', 'now')"))
            now = datetime.fromisoformat(str(raw)).replace(tzinfo=UTC)
        else:
            value = s.scalar(select(func.clock_timestamp()))  # PostgreSQL; now() = txn start
            assert isinstance(value, datetime) and value.tzinfo is not None
            now = value.astimezone(UTC)
        s.info["now"] = now
        return now

    def _fail_if_exhausted(self, s: Session, job: Job) -> bool:
        """Fail the job if it was claimed ``max_attempts`` times already; returns whether."""
        if job.attempts < self.max_attempts:
            return False
        detail = (
            f"the job's worker died {job.attempts} times (OOM kill or crash?); giving up after "
            f"{self.max_attempts} attempts (DCSEG_MAX_ATTEMPTS). Retry with a smaller "
            "capture or preset, or on a worker with more memory"
        )
        error = {"type": "too-many-attempts", "detail": detail, "attempts": job.attempts}
        self._finish(s, job, "failed", error, f"failed after {job.attempts} attempts")
        return True

    def _set(self, s: Session, job: Job, **changes: Any) -> None:
        for name, value in changes.items():
            setattr(job, name, value)
        job.updated_at = self._now(s)
        self._event(s, job, "status", {"status": job.status, "message": job.message})

    def _finish(
        self, s: Session, job: Job, status: str, error: dict[str, Any] | None, message: str
    ) -> None:
        job.status, job.error, job.message = status, error, message or None
        job.completed_at = job.updated_at = self._now(s)
        if status == "succeeded":
            job.progress = 1.0
        data = {"status": status, "message": job.message, "error": error}
        self._event(s, job, "completed", data)

    def _event(self, s: Session, job: Job, type_: str, data: dict[str, Any]) -> None:
        job.event_seq += 1
        now = self._now(s)
        s.add(Event(job_id=job.id, seq=job.event_seq, type=type_, data=data, created_at=now))
