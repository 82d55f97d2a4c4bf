"""Issue 17, job store: attempts cap, atomic tenant cap, SQLite locking, database clock for
leases, derived jobs whose parent vanished, and cancels acknowledged before the job ended.

Tests that take a ``db_url`` or ``store`` run on SQLite and on PostgreSQL (the parametrised
fixtures of ``test_databases``).
"""

from __future__ import annotations

import shutil
import sqlite3
import threading
from collections.abc import Callable, Iterator
from datetime import datetime, timedelta
from pathlib import Path
from typing import Any

import pytest
from pydantic import ValidationError

from jobstore.contract import JobPaths
from jobstore.models import Job, utcnow
from jobstore.settings import Settings
from jobstore.store import Store, engine, events, idempotency, jobs, leases, new_id
from service.deps import AppState
from service.problems import ApiProblem
from service.routes.jobs import _new_job
from service.schemas import JobCreate
from tests.service import test_databases
from tests.service.conftest import make_settings
from tests.worker.fakes import FakeStage, RecordingQueue
from worker.execute import execute_job, read_manifest

LEASE = timedelta(seconds=60)

# the parametrised SQLite/PostgreSQL fixtures
postgres_server = test_databases.postgres_server
db_url = test_databases.db_url
store = test_databases.store


def _job(store: Store, parent: str | None = None) -> str:
    job = Job(
        id=new_id(),
        tenant_id="t",
        upload_id="u1",
        parent_job_id=parent,
        status="queued",
        config={"preset": "fast", "options": {}},
        event_seq=0,
    )
    return store.create_job(job).id


def _die(store: Store, job_id: str, times: int) -> None:
    """``times`` workers claim the job and die (each next claim takes the stale lease over)."""
    for i in range(times):
        assert store.claim_job(job_id, f"w{i}", timedelta(0)) is not None


# ----- 1. attempts -----
def test_attempts_capped_claim_fails_job_after_max_attempts(store):
    """Defect 1: `attempts` is counted but never checked (a crashing job is re-queued forever)."""
    job_id = _job(store)
    _die(store, job_id, 3)  # the default cap
    assert store.claim_job(job_id, "w-next", timedelta(0)) is None
    job = store.get_job(job_id)
    assert job.status == "failed" and job.attempts == 3
    assert job.error["type"] == "too-many-attempts"
    assert "3 times" in job.error["detail"] and "DCSEG_MAX_ATTEMPTS" in job.error["detail"]
    assert store.events_after(job_id, 0)[-1].type == "completed"


def test_attempts_capped_requeue_stale_fails_job_at_cap(store):
    """Defect 1: the lease sweep must fail, not requeue, a job whose worker died N times."""
    below, at_cap = _job(store), _job(store)
    _die(store, below, 2)
    _die(store, at_cap, 3)
    assert store.requeue_stale(timedelta(0)) == [below]
    assert store.get_job(below).status == "queued"
    failed = store.get_job(at_cap)
    assert failed.status == "failed" and failed.error["type"] == "too-many-attempts"


def test_attempts_capped_requeue_running_fails_job_at_cap(store):
    """Defect 1: the embedded startup sweep must fail, not requeue, a job at the cap."""
    below, at_cap = _job(store), _job(store)
    _die(store, below, 1)
    _die(store, at_cap, 3)
    assert store.requeue_running() == [below]
    assert store.get_job(at_cap).status == "failed"


def test_attempts_cap_is_a_store_setting(db_url):
    """Defect 1: the cap is the ``max_attempts`` setting (here 1: the first death fails it)."""
    settings = make_settings(Path("/nonexistent"), database_url=db_url, max_attempts=1)
    capped = Store.from_settings(settings)
    try:
        capped.init_schema()
        capped.ensure_tenant("t")
        job_id = _job_with_upload(capped)
        _die(capped, job_id, 1)
        assert capped.requeue_stale(timedelta(0)) == []
        failed = capped.get_job(job_id)
        assert failed is not None and failed.error is not None
        assert failed.error["type"] == "too-many-attempts"
    finally:
        capped.close()


def _job_with_upload(store: Store) -> str:
    from jobstore.models import Upload

    if store.get_upload("u1", "t") is None:
        store.add_upload(
            Upload(id="u1", tenant_id="t", sha256="0" * 64, size=1, content_type="x", summary={})
        )
    return _job(store)


@pytest.fixture
def worker_env(store: Store, tmp_path: Path) -> Settings:
    """Settings whose storage holds the fixture upload ``u1`` (an empty capture)."""
    settings = make_settings(tmp_path, database_url=store.url, heartbeat_s=0.1)
    (settings.storage_dir / "uploads" / "u1" / "data").mkdir(parents=True)
    return settings


def test_attempts_interrupted_run_is_not_counted(store, worker_env):
    """Defect 1: a run stopped by a worker shutdown is no crash; it must not use up an attempt."""
    job_id = _job(store)
    for _ in range(4):  # more shutdowns than the cap allows crashes
        status = execute_job(
            job_id, store, worker_env, stages=[FakeStage("one")], interrupt=lambda: True
        )
        assert status == "interrupted"
        assert store.get_job(job_id).attempts == 0
        assert store.requeue_running() == [job_id]
    assert execute_job(job_id, store, worker_env, stages=[FakeStage("one")]) == "succeeded"


# ----- 2. per-tenant cap -----
def test_tenant_job_cap_is_atomic_under_concurrent_posts(store, tmp_path, monkeypatch):
    """Defect 2: per-tenant job cap is check-then-insert in two transactions."""
    cap, callers = 2, 6
    settings = make_settings(tmp_path, database_url=store.url, max_running_jobs_per_tenant=cap)
    state = AppState(settings=settings, store=store, queue=RecordingQueue())
    barrier = threading.Barrier(callers)
    insert: Callable[..., Job] = store.create_job

    def create_together(job: Job, **kwargs: Any) -> Job:
        barrier.wait(timeout=30)  # every caller has passed any check made before the insert
        return insert(job, **kwargs)

    monkeypatch.setattr(store, "create_job", create_together)
    accepted, refused = [], []

    def post() -> None:
        try:
            accepted.append(_new_job(state, "t", JobCreate(upload_id="u1")).id)
        except ApiProblem as problem:
            refused.append(problem)

    threads = [threading.Thread(target=post) for _ in range(callers)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert len(accepted) == cap and store.count_active("t") == cap
    assert len(refused) == callers - cap
    assert all(p.status == 429 and "the limit is 2" in p.detail for p in refused)


# ----- 3. SQLite locking -----
@pytest.fixture
def sqlite_store(tmp_path: Path) -> Iterator[Store]:
    store = Store(f"sqlite:///{tmp_path / 'store.db'}")
    store.init_schema()
    store.ensure_tenant("t")
    _job_with_upload(store)
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


def test_settings_busy_timeout_must_be_shorter_than_stale_lease_window():
    """Defect 3: the 30 s busy timeout equals the 30 s stale-lease window."""
    with pytest.raises(ValidationError, match="sqlite_busy_timeout_s .* 3 \\* heartbeat_s"):
        Settings(heartbeat_s=10.0, sqlite_busy_timeout_s=30.0)
    assert Settings(heartbeat_s=10.0, sqlite_busy_timeout_s=29.0).busy_timeout_s == 29.0
    assert Settings(heartbeat_s=10.0).busy_timeout_s == 5.0


# ----- 4. database clock -----
def _skew(monkeypatch: pytest.MonkeyPatch, offset: timedelta) -> None:
    """The Python clock of this process (as any part of the store would read it) is
    ``offset`` off."""
    for part in (engine, events, idempotency, jobs, leases):
        monkeypatch.setattr(part, "utcnow", lambda: utcnow() + offset, raising=False)


def test_lease_uses_database_clock_when_worker_clock_is_behind(store, monkeypatch):
    """Defect 4: leases compare the worker's clock with the API's (a live job looked dead)."""
    job_id = _job(store)
    _skew(monkeypatch, -timedelta(days=1))  # the worker's clock
    assert store.claim_job(job_id, "w", LEASE) is not None
    assert store.heartbeat(job_id, "w") == "ok"
    monkeypatch.undo()  # the API's clock is right
    assert store.requeue_stale(LEASE) == []
    assert store.unfinished(LEASE) == []
    beat = store.get_job(job_id).heartbeat_at
    assert abs(beat - datetime.now(beat.tzinfo)) < timedelta(hours=1)


def test_lease_uses_database_clock_when_claimer_clock_is_ahead(store, monkeypatch):
    """Defect 4: a second delivery on a host whose clock runs ahead stole a live lease."""
    job_id = _job(store)
    assert store.claim_job(job_id, "w1", LEASE) is not None
    _skew(monkeypatch, timedelta(days=1))
    assert store.claim_job(job_id, "w2", LEASE) is None
    assert store.requeue_stale(LEASE) == []
    assert store.get_job(job_id).worker == "w1"
    assert store.requeue_stale(timedelta(0)) == [job_id]  # a zero window still sees it stale


# ----- 5. derived jobs and cancels -----
def test_derived_job_redoes_stage_whose_parent_files_vanished(store, worker_env):
    """Defect 5: a parent job deleted while a derived job links its files yields an empty
    stage marked done."""
    parent = _job(store)
    assert execute_job(parent, store, worker_env, stages=[FakeStage("one")]) == "succeeded"
    shutil.rmtree(JobPaths(worker_env.storage_dir, parent).output / "one")  # manifest remains
    child, stage = _job(store, parent=parent), FakeStage("one")
    assert execute_job(child, store, worker_env, stages=[stage]) == "succeeded"
    assert stage.runs == 1
    paths = JobPaths(worker_env.storage_dir, child)
    assert set(read_manifest(paths)["stages"][0]["files"]) == {"one/out.txt"}
    assert (paths.output / "one" / "out.txt").read_bytes() == b"hello"


def test_derived_job_reuses_intact_parent_stage(store, worker_env):
    """Defect 5 (no regression): an intact parent stage is still linked, not recomputed."""
    parent = _job(store)
    assert execute_job(parent, store, worker_env, stages=[FakeStage("one")]) == "succeeded"
    child, stage = _job(store, parent=parent), FakeStage("one")
    assert execute_job(child, store, worker_env, stages=[stage]) == "succeeded"
    assert stage.runs == 0
    assert read_manifest(JobPaths(worker_env.storage_dir, child))["stages"][0]["details"] == {
        "reused": True
    }


def test_canceling_job_finishing_ends_canceled(store):
    """Defect 5: a job acknowledged as canceling can end succeeded."""
    job_id = _job(store)
    assert store.claim_job(job_id, "w", LEASE) is not None
    assert store.request_cancel(job_id, "t").status == "canceling"
    assert store.finish_job(job_id, "succeeded", worker="w") == "canceled"
    job = store.get_job(job_id)
    assert job.status == "canceled" and job.progress < 1.0
    assert store.events_after(job_id, 0)[-1].data["status"] == "canceled"


# ----- replicas starting together -----
@pytest.mark.integration
def test_replicas_starting_together_both_sync_their_keys(postgres_server, monkeypatch):
    """Found by the deployed load benchmark: two API processes starting on a fresh database
    both insert the tenant of their keys; the loser failed startup with a unique violation.
    Another replica's insert lands between this one's check and its insert."""
    from jobstore.models import Tenant

    url = postgres_server
    test_databases._reset(url)
    first, other = Store(url), Store(url)
    first.init_schema()
    raced: list[str] = []

    def racing(s: Any, tenant: str) -> None:
        missing = s.get(Tenant, tenant) is None
        if missing and not raced:
            raced.append(tenant)
            other.ensure_tenant(tenant)  # the other replica commits first
        if missing:
            s.add(Tenant(id=tenant))

    monkeypatch.setattr(Store, "_ensure_tenant", staticmethod(racing))
    try:
        hashes = first.sync_api_keys({"k" * 16: "bench"})
        assert raced == ["bench"] and list(hashes.values()) == ["bench"]
        assert other.sync_api_keys({"k" * 16: "bench"}) == hashes
    finally:
        first.close()
        other.close()
