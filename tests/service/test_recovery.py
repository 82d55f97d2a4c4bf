"""The broker-mode sweeps: jobs are sent again at startup, after the broker lost its messages,
and after a startup the broker was down for (no Redis needed: a recording queue)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from jobstore.models import Job, Upload
from jobstore.settings import Settings
from jobstore.store import Store, new_id
from service.main import recover_once, sweep
from tests.service.conftest import make_settings
from tests.worker.fakes import RecordingQueue


class DownQueue(RecordingQueue):
    """A broker that refuses connections."""

    def enqueue(self, job_id: str) -> None:
        raise ConnectionError("broker down")


@pytest.fixture
def broker_settings(tmp_path: Path) -> Settings:
    return make_settings(tmp_path, broker_url="redis://127.0.0.1:1/0")


@pytest.fixture
def store(broker_settings: Settings) -> Iterator[Store]:
    broker_settings.storage_dir.mkdir(parents=True)
    store = Store(broker_settings.db_url)
    store.init_schema()
    store.ensure_tenant("t")
    store.add_upload(
        Upload(id="u1", tenant_id="t", sha256="0" * 64, size=1, content_type="x", summary={})
    )
    yield store
    store.close()


def add_job(store: Store, status: str = "queued") -> str:
    job = Job(id=new_id(), tenant_id="t", upload_id="u1", status=status, config={}, event_seq=0)
    return store.create_job(job).id


def test_startup_sweep_sends_queued_jobs_and_marks_the_queue(store, broker_settings):
    queued = [add_job(store), add_job(store)]
    add_job(store, status="succeeded")
    queue = RecordingQueue(intact=False)
    assert sweep(store, queue, broker_settings)
    assert queue.job_ids == queued
    assert queue.intact


def test_recovery_resends_queued_jobs_only_when_the_broker_lost_them(store, broker_settings):
    queued = add_job(store)
    queue = RecordingQueue()
    recover_once(store, queue, broker_settings, resend=False)
    assert queue.job_ids == []  # intact broker: no duplicates every sweep
    queue.intact = False  # e.g. Redis restarted without persistence
    recover_once(store, queue, broker_settings, resend=False)
    assert queue.job_ids == [queued]
    assert queue.intact
    recover_once(store, queue, broker_settings, resend=False)
    assert queue.job_ids == [queued]


def test_jobs_the_startup_sweep_could_not_send_are_sent_later(store, broker_settings):
    queued = add_job(store)
    assert not sweep(store, DownQueue(intact=False), broker_settings)
    queue = RecordingQueue()  # the broker is back, its marker intact (e.g. Redis with AOF)
    recover_once(store, queue, broker_settings, resend=True)
    assert queue.job_ids == [queued]


def test_a_failed_resend_leaves_the_queue_unmarked(store, broker_settings):
    add_job(store)
    queue = DownQueue(intact=False)
    with pytest.raises(ConnectionError):
        recover_once(store, queue, broker_settings, resend=False)
    assert not queue.intact  # so the next sweep tries again
