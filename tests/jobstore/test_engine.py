"""The store's engine (:mod:`jobstore.store.engine`) on SQLite: reads take no write lock,
writes take it up front and wait at most the configured busy timeout.
"""

from __future__ import annotations

import sqlite3
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from jobstore.settings import Settings
from jobstore.store import Store
from tests.jobstore.conftest import LEASE, add_job
from tests.service.conftest import make_settings


@pytest.fixture
def sqlite_store(tmp_path: Path) -> Iterator[Store]:
    store = Store(f"sqlite:///{tmp_path / 'store.db'}")
    store.init_schema()
    store.ensure_tenant("t")
    add_job(store)
    yield store
    store.close()


@pytest.fixture
def write_lock(sqlite_store: Store) -> Iterator[Callable[[], None]]:
    """Another connection holding the database's write lock (``BEGIN IMMEDIATE``)."""
    path = sqlite_store.url.removeprefix("sqlite:///")
    other = sqlite3.connect(path, isolation_level=None, timeout=0)
    other.execute("BEGIN IMMEDIATE")

    def release() -> None:
        other.execute("ROLLBACK")

    yield release
    other.close()


def test_sqlite_read_does_not_take_write_lock(sqlite_store, write_lock):
    """Defect 3: SQLite: every transaction, reads included, starts with BEGIN IMMEDIATE."""
    job_id = sqlite_store.next_queued()
    assert job_id is not None
    assert sqlite_store.get_job(job_id).status == "queued"
    assert [j.id for j in sqlite_store.list_jobs("t", status=None, after=None, limit=5)[0]] == [
        job_id
    ]
    assert sqlite_store.count_active("t") == 1
    assert sqlite_store.events_after(job_id, 0)[0].type == "status"
    assert sqlite_store.unfinished(LEASE) == [job_id]
    sqlite_store.ping()  # /readyz


def test_sqlite_writes_begin_immediate_with_the_configured_busy_timeout(sqlite_store, write_lock):
    """Defect 3: writes still take the write lock up front, and give up after the busy timeout."""
    from sqlalchemy.exc import OperationalError

    impatient = Store(sqlite_store.url, busy_timeout_s=0.2)
    try:
        job_id = impatient.next_queued()
        assert job_id is not None
        with pytest.raises(OperationalError, match="locked"):
            impatient.claim_job(job_id, "w", LEASE)
        write_lock()
        assert impatient.claim_job(job_id, "w", LEASE) is not None
    finally:
        impatient.close()


def test_sqlite_busy_timeout_comes_from_settings(tmp_path):
    """Defect 3: the SQLite busy timeout is a setting (default: half a heartbeat interval)."""
    settings = make_settings(tmp_path, heartbeat_s=4.0, sqlite_busy_timeout_s=2.5)
    settings.storage_dir.mkdir(parents=True)
    default = Settings(storage_dir=settings.storage_dir, heartbeat_s=0.4)
    for configured, expected_ms in ((settings, 2500), (default, 200)):
        store = Store.from_settings(configured)
        try:
            with store.engine.connect() as conn:
                assert conn.exec_driver_sql("PRAGMA busy_timeout").scalar() == expected_ms
        finally:
            store.close()


def test_a_connection_in_use_at_close_is_closed_when_returned(sqlite_store):
    """A sweep thread past the shutdown deadline still holds a connection when the store
    closes: returning it must close it (else it stays open in the old pool until garbage
    collection, where psycopg warns)."""
    conn = sqlite_store.engine.connect()
    raw = conn.connection.dbapi_connection
    assert raw is not None
    sqlite_store.close()
    raw.execute("SELECT 1")  # still usable by its holder
    conn.close()
    with pytest.raises(sqlite3.ProgrammingError, match="closed"):
        raw.execute("SELECT 1")
    assert sqlite_store.get_job("missing") is None  # a store used again reconnects
