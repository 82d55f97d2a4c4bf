"""The database connection every part of the store shares: engine, sessions and clock.

SQLite gets WAL, foreign keys and ``BEGIN IMMEDIATE`` write transactions (reads a deferred
``BEGIN``); PostgreSQL locks rows with ``SELECT ... FOR UPDATE``. Lease, start, update and
completion times come from the database's clock (:meth:`StoreBase._now`), never a host's.
"""

from __future__ import annotations

import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from datetime import UTC, datetime
from typing import TYPE_CHECKING, Any, Self

from sqlalchemy import Connection, create_engine, event, func, select, text
from sqlalchemy.engine import Engine
from sqlalchemy.orm import Session, sessionmaker
from sqlalchemy.pool import ConnectionPoolEntry

from jobstore.models import Job

if TYPE_CHECKING:
    from jobstore.settings import Settings

READ_ONLY = "dcseg_read_only"
"""Execution option of read sessions: SQLite opens them with a deferred ``BEGIN``."""


def new_id() -> str:
    return str(uuid.uuid4())


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


def _close_on_checkin(dbapi_conn: Any, record: ConnectionPoolEntry) -> None:
    if dbapi_conn is not None:
        record.invalidate()  # closes it; a later checkout (store reused) connects again


class StoreBase:
    """The engine and its sessions; each part of :class:`jobstore.store.Store` builds on it."""

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
    def from_settings(cls, settings: Settings) -> Self:
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
        """Close the pooled connections. One still checked out (a thread past the API's
        shutdown deadline) is closed when it is returned, not left open in the old pool."""
        if not event.contains(self.engine, "checkin", _close_on_checkin):
            event.listen(self.engine, "checkin", _close_on_checkin)
        self.engine.dispose()

    def ping(self) -> None:
        """Raise unless the database answers (a read: no SQLite write lock)."""
        with self.engine.execution_options(**{READ_ONLY: True}).connect() as conn:
            conn.exec_driver_sql("SELECT 1")

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
