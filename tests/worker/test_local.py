"""The embedded worker: runs queued jobs from the store, and is restarted when it dies."""

from __future__ import annotations

import os
import signal

from tests.service.conftest import wait_for
from tests.worker.conftest import add_job
from worker.local import EmbeddedWorker


def test_process_worker_is_restarted_after_a_crash(store, settings):
    worker = EmbeddedWorker(settings, mode="process")
    worker.start()
    try:
        assert worker.alive()
        process = worker._process
        assert process is not None and process.pid is not None
        os.kill(process.pid, signal.SIGKILL)
        process.join(10)
        assert not worker.alive()
        worker.ensure_running()
        assert worker.alive() and worker._process is not process
    finally:
        worker.stop()
    assert not worker.alive()


def test_thread_worker_runs_a_queued_job_and_stops(store, settings):
    job_id = add_job(store)  # the default stages fail on the empty upload folder: still ends
    worker = EmbeddedWorker(settings, mode="thread")
    worker.start()
    try:
        wait_for(lambda: store.get_job(job_id).status == "failed", timeout=60)
    finally:
        worker.stop()
    job = store.get_job(job_id)
    assert job.error["type"] == "invalid-input"
    assert not worker.alive()
