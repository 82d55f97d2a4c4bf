"""Leases (:mod:`jobstore.store.leases`): a job claimed ``max_attempts`` times fails, lease
times come from the database's clock, and a cancel acknowledged before the job ended wins.
On SQLite and PostgreSQL (``tests/jobstore/conftest.py``).
"""

from __future__ import annotations

from datetime import datetime, timedelta
from pathlib import Path

import pytest

from jobstore.models import utcnow
from jobstore.store import Store, engine, events, idempotency, jobs, leases
from tests.jobstore.conftest import LEASE, add_job
from tests.service.conftest import make_settings


def _die(store: Store, job_id: str, times: int) -> None:
    """``times`` workers claim the job and die (each next claim takes the stale lease over)."""
    for i in range(times):
        assert store.claim_job(job_id, f"w{i}", timedelta(0)) is not None


# ----- attempts -----
def test_attempts_capped_claim_fails_job_after_max_attempts(store):
    """Defect 1: `attempts` is counted but never checked (a crashing job is re-queued forever)."""
    job_id = add_job(store)
    _die(store, job_id, 3)  # the default cap
    assert store.claim_job(job_id, "w-next", timedelta(0)) is None
    job = store.get_job(job_id)
    assert job.status == "failed" and job.attempts == 3
    assert job.error["type"] == "too-many-attempts"
    assert "3 times" in job.error["detail"] and "DCSEG_MAX_ATTEMPTS" in job.error["detail"]
    assert store.events_after(job_id, 0)[-1].type == "completed"


def test_attempts_capped_requeue_stale_fails_job_at_cap(store):
    """Defect 1: the lease sweep must fail, not requeue, a job whose worker died N times."""
    below, at_cap = add_job(store), add_job(store)
    _die(store, below, 2)
    _die(store, at_cap, 3)
    assert store.requeue_stale(timedelta(0)) == [below]
    assert store.get_job(below).status == "queued"
    failed = store.get_job(at_cap)
    assert failed.status == "failed" and failed.error["type"] == "too-many-attempts"


def test_attempts_capped_requeue_running_fails_job_at_cap(store):
    """Defect 1: the embedded startup sweep must fail, not requeue, a job at the cap."""
    below, at_cap = add_job(store), add_job(store)
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
        job_id = add_job(capped)
        _die(capped, job_id, 1)
        assert capped.requeue_stale(timedelta(0)) == []
        failed = capped.get_job(job_id)
        assert failed is not None and failed.error is not None
        assert failed.error["type"] == "too-many-attempts"
    finally:
        capped.close()


# ----- the database's clock -----
def _skew(monkeypatch: pytest.MonkeyPatch, offset: timedelta) -> None:
    """The Python clock of this process (as any part of the store would read it) is
    ``offset`` off."""
    for part in (engine, events, idempotency, jobs, leases):
        monkeypatch.setattr(part, "utcnow", lambda: utcnow() + offset, raising=False)


def test_lease_uses_database_clock_when_worker_clock_is_behind(store, monkeypatch):
    """Defect 4: leases compare the worker's clock with the API's (a live job looked dead)."""
    job_id = add_job(store)
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
    job_id = add_job(store)
    assert store.claim_job(job_id, "w1", LEASE) is not None
    _skew(monkeypatch, timedelta(days=1))
    assert store.claim_job(job_id, "w2", LEASE) is None
    assert store.requeue_stale(LEASE) == []
    assert store.get_job(job_id).worker == "w1"
    assert store.requeue_stale(timedelta(0)) == [job_id]  # a zero window still sees it stale


# ----- cancels -----
def test_canceling_job_finishing_ends_canceled(store):
    """Defect 5: a job acknowledged as canceling can end succeeded."""
    job_id = add_job(store)
    assert store.claim_job(job_id, "w", LEASE) is not None
    assert store.request_cancel(job_id, "t").status == "canceling"
    assert store.finish_job(job_id, "succeeded", worker="w") == "canceled"
    job = store.get_job(job_id)
    assert job.status == "canceled" and job.progress < 1.0
    assert store.events_after(job_id, 0)[-1].data["status"] == "canceled"
