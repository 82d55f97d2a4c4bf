"""The job store on SQLite and on the real PostgreSQL (a fresh database per test run).

PostgreSQL cases are ``integration`` tests: they run wherever PostgreSQL answers on
``DCSEG_TEST_POSTGRES`` (default ``postgresql+psycopg://postgres@127.0.0.1:5432/test``) and
skip with the reason otherwise.
"""

from __future__ import annotations

import os
import threading
import uuid
from collections.abc import Iterator
from datetime import timedelta
from pathlib import Path

import pytest
from sqlalchemy import insert
from sqlalchemy.engine import make_url

from jobstore.models import SCHEMA_VERSION, Job, SchemaVersion, Upload
from jobstore.store import Cursor, SchemaError, Store, new_id
from service.main import create_app
from tests.service.conftest import (
    AUTH_A,
    AUTH_B,
    TAR,
    TestClient,
    make_settings,
    reachable,
    state_of,
)
from tests.worker.fakes import FakeStage
from worker.execute import execute_job

ADMIN_URL = os.environ.get(
    "DCSEG_TEST_POSTGRES", "postgresql+psycopg://postgres@127.0.0.1:5432/test"
)


def _reachable(url: str) -> bool:
    parsed = make_url(url)
    return reachable(parsed.host or "127.0.0.1", parsed.port or 5432)


@pytest.fixture(scope="module")
def postgres_server() -> Iterator[str]:
    """A fresh database ``dcseg_test_<random>``, dropped afterwards; yields its URL."""
    if not _reachable(ADMIN_URL):
        pytest.skip(f"PostgreSQL not reachable at {make_url(ADMIN_URL).render_as_string()}")
    import psycopg

    admin = make_url(ADMIN_URL)
    name = f"dcseg_test_{uuid.uuid4().hex[:12]}"
    dsn = admin.set(drivername="postgresql").render_as_string(hide_password=False)
    with psycopg.connect(dsn, autocommit=True) as conn:
        conn.execute(f'CREATE DATABASE "{name}"')
    try:
        yield admin.set(database=name).render_as_string(hide_password=False)
    finally:
        with psycopg.connect(dsn, autocommit=True) as conn:
            conn.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')


def _reset(url: str) -> None:
    store = Store(url)
    from jobstore.models import Base

    Base.metadata.drop_all(store.engine)
    store.close()


@pytest.fixture(params=["sqlite", pytest.param("postgresql", marks=pytest.mark.integration)])
def db_url(request, tmp_path: Path) -> Iterator[str]:
    if request.param == "sqlite":
        yield f"sqlite:///{tmp_path / 'store.db'}"
        return
    url = request.getfixturevalue("postgres_server")
    _reset(url)
    yield url
    _reset(url)


@pytest.fixture
def store(db_url: str) -> Iterator[Store]:
    store = Store(db_url)
    assert store.init_schema() == SCHEMA_VERSION
    store.ensure_tenant("t")
    store.add_upload(
        Upload(
            id="u1", tenant_id="t", sha256="0" * 64, size=3 * 2**31, content_type="x", summary={}
        )
    )
    yield store
    store.close()


def _job(store: Store, status: str = "queued") -> str:
    job = Job(id=new_id(), tenant_id="t", upload_id="u1", status=status, config={}, event_seq=0)
    return store.create_job(job).id


def test_schema_is_versioned(store, db_url):
    again = Store(db_url)
    try:
        assert again.init_schema() == SCHEMA_VERSION  # idempotent
        with store.engine.begin() as conn:
            conn.execute(insert(SchemaVersion).values(version=SCHEMA_VERSION + 1))
        with pytest.raises(SchemaError, match="newer"):
            again.init_schema()
    finally:
        again.close()


def test_big_upload_sizes_fit(store):
    assert store.get_upload("u1", "t").size == 3 * 2**31
    assert store.get_upload("u1", "other") is None


def test_lifecycle_and_event_sequence(store):
    job_id = _job(store)
    assert store.claim_job(job_id, "w", timedelta(seconds=30)) is not None
    assert store.report_progress(job_id, "w", ("one", 0, 2), 0.25, "a") == "ok"
    assert store.report_progress(job_id, "other", ("one", 0, 2), 0.25, "a") == "lost"
    assert store.request_cancel(job_id, "t").status == "canceling"
    assert store.report_progress(job_id, "w", ("one", 0, 2), 0.5, "b") == "cancel"
    assert store.heartbeat(job_id, "w") == "cancel"
    assert not store.finish_job(job_id, "succeeded", worker="other")
    assert store.finish_job(job_id, "canceled", worker="w")
    events = store.events_after(job_id, 0)
    assert [e.seq for e in events] == list(range(1, len(events) + 1))
    assert events[-1].type == "completed" and events[-1].data["status"] == "canceled"
    assert [e.seq for e in store.events_after(job_id, 3)] == [e.seq for e in events[3:]]
    job = store.get_job(job_id)
    assert job.completed_at.tzinfo is not None and job.completed_at >= job.created_at


def test_concurrent_claims_have_one_winner(store):
    job_id = _job(store)
    winners, barrier = [], threading.Barrier(4)

    def claim(worker: str) -> None:
        barrier.wait()
        if store.claim_job(job_id, worker, timedelta(seconds=60)) is not None:
            winners.append(worker)

    threads = [threading.Thread(target=claim, args=(f"w{i}",)) for i in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(winners) == 1


def test_concurrent_events_never_collide(store):
    job_id = _job(store)

    def log(i: int) -> None:
        for k in range(10):
            store.log(job_id, f"{i}-{k}")

    threads = [threading.Thread(target=log, args=(i,)) for i in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    seqs = [e.seq for e in store.events_after(job_id, 0)]
    assert seqs == list(range(1, 32))


def test_listing_order_and_cursor(store):
    ids = [_job(store) for _ in range(5)]
    page, more = store.list_jobs("t", status=None, after=None, limit=3)
    assert [j.id for j in page] == ids[::-1][:3] and more
    rest, more = store.list_jobs(
        "t", status=None, after=Cursor(page[-1].created_at, page[-1].id), limit=3
    )
    assert [j.id for j in rest] == ids[::-1][3:] and not more


def test_idempotency_records(store):
    assert store.idempotency_begin("t", "k", "h1").kind == "new"
    assert store.idempotency_begin("t", "k", "h1").kind == "in_flight"
    assert store.idempotency_begin("t", "k", "h2").kind == "mismatch"
    store.idempotency_finish("t", "k", 202, {"body": {"id": "x"}, "headers": {}})
    replay = store.idempotency_begin("t", "k", "h1")
    assert replay.kind == "replay" and replay.status_code == 202
    assert store.idempotency_begin("other", "k", "h2").kind == "new"


def test_sweeps(store):
    queued, running = _job(store), _job(store)
    store.claim_job(running, "w", timedelta(seconds=60))
    assert set(store.unfinished(timedelta(seconds=60))) == {queued}
    assert set(store.unfinished(timedelta(0))) == {queued, running}
    assert store.requeue_stale(timedelta(seconds=60)) == []
    assert store.requeue_stale(timedelta(0)) == [running]
    assert store.heartbeat(running, "w") == "lost"  # the old worker must stop
    store.claim_job(running, "w2", timedelta(seconds=60))
    assert store.requeue_running() == [running]
    assert store.get_job(running).status == "queued"


def test_api_flow(db_url, tmp_path, scene_tar):
    settings = make_settings(tmp_path, database_url=db_url)
    with TestClient(create_app(settings)) as client:
        upload = client.post("/v1/uploads", content=scene_tar, headers={**AUTH_A, **TAR})
        assert upload.status_code == 201, upload.text
        job = client.post(
            "/v1/jobs", json={"upload_id": upload.json()["id"]}, headers=AUTH_A
        ).json()
        state = state_of(client)
        assert (
            execute_job(job["id"], state.store, state.settings, stages=[FakeStage("one")])
            == "succeeded"
        )
        assert client.get(f"/v1/jobs/{job['id']}", headers=AUTH_A).json()["status"] == "succeeded"
        assert client.get(f"/v1/jobs/{job['id']}", headers=AUTH_B).status_code == 404
        assert [j["id"] for j in client.get("/v1/jobs", headers=AUTH_A).json()["jobs"]] == [
            job["id"]
        ]
        assert client.delete(f"/v1/jobs/{job['id']}", headers=AUTH_A).status_code == 204
