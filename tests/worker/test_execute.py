"""``execute_job`` without Celery: stages, manifest, resume, cancel, failures, leases."""

from __future__ import annotations

import json
import logging
import time
from datetime import timedelta

import pytest

from dcseg.errors import InputError
from jobstore.blobstore import LocalStorage
from jobstore.contract import JobPaths
from service.main import create_app
from tests.service.conftest import AUTH_A, TAR, TestClient, make_settings, state_of, tar_bytes
from tests.worker.conftest import add_job
from tests.worker.fakes import FakeStage
from worker.execute import execute_job


def test_runs_stages_and_writes_manifest(store, settings):
    job_id = add_job(store)
    stages = [FakeStage("one"), FakeStage("two", files={"a/b.txt": b"x"})]
    assert execute_job(job_id, store, settings, stages=stages) == "succeeded"
    paths = JobPaths(settings.storage_dir, job_id)
    manifest = json.loads(paths.manifest.read_text())
    assert [s["name"] for s in manifest["stages"]] == ["one", "two"]
    assert manifest["stages"][1]["files"]["two/a/b.txt"]["size"] == 1
    names = [a.name for a in LocalStorage(settings.storage_dir).files("t", job_id)]
    assert names == ["one/out.txt", "two/a/b.txt"]
    assert not list(paths.output.glob(".tmp-*"))
    job = store.get_job(job_id)
    assert job.status == "succeeded" and job.progress == 1.0 and job.attempts == 1
    types = [e.type for e in store.events_after(job_id, 0)]
    assert types[0] == "status" and types[-1] == "completed" and "progress" in types


def test_redelivered_job_resumes_after_last_finished_stage(store, settings):
    job_id = add_job(store)
    stop = {"now": False}

    def die_in_stage_two(i):
        stop["now"] = True

    one, two = FakeStage("one"), FakeStage("two", on_step=die_in_stage_two)
    status = execute_job(job_id, store, settings, stages=[one, two], interrupt=lambda: stop["now"])
    assert status == "interrupted" and store.get_job(job_id).status == "running"
    # a stray partial output of stage two, as if the worker died mid-write
    (JobPaths(settings.storage_dir, job_id).output / "two").mkdir()
    # while the lease is fresh a duplicate delivery must not run it
    store.heartbeat(job_id, store.get_job(job_id).worker)
    assert execute_job(job_id, store, settings, stages=[one, two]) == "skipped"
    time.sleep(3 * settings.heartbeat_s + 0.1)
    two.on_step = None
    assert execute_job(job_id, store, settings, stages=[one, two]) == "succeeded"
    assert one.runs == 1 and two.runs == 2
    job = store.get_job(job_id)
    assert job.attempts == 1 and job.status == "succeeded"  # the interrupted run is no crash
    names = [a.name for a in LocalStorage(settings.storage_dir).files("t", job_id)]
    assert names == ["one/out.txt", "two/out.txt"]


def test_cancel_flag_stops_between_iterations(store, settings):
    job_id = add_job(store)

    def cancel(i):
        if i == 2:
            store.request_cancel(job_id, "t")

    stage = FakeStage("one", steps=10, on_step=cancel)
    assert execute_job(job_id, store, settings, stages=[stage, FakeStage("two")]) == "canceled"
    job = store.get_job(job_id)
    assert job.status == "canceled" and job.completed_at is not None
    assert not (JobPaths(settings.storage_dir, job_id).output / "two").exists()


@pytest.mark.parametrize(
    ("error", "kind"),
    [
        (RuntimeError("boom"), "internal"),
        (InputError.single("rgb/1.png", "unreadable"), "invalid-input"),
    ],
)
def test_failures_are_recorded(store, settings, error, kind):
    job_id = add_job(store)
    assert execute_job(job_id, store, settings, stages=[FakeStage("one", fail=error)]) == "failed"
    job = store.get_job(job_id)
    assert job.status == "failed" and job.error["type"] == kind
    if kind == "invalid-input":
        assert job.error["errors"] == [{"path": "rgb/1.png", "reason": "unreadable"}]


def test_stage_time_limit(store, settings):
    limited = settings.model_copy(update={"stage_time_limit_s": {"slow": 0.05}})
    job_id = add_job(store)
    stage = FakeStage("slow", steps=5, on_step=lambda i: time.sleep(0.03))
    assert execute_job(job_id, store, limited, stages=[stage]) == "failed"
    assert store.get_job(job_id).error["type"] == "timeout"


def test_finished_jobs_are_not_run_again(store, settings):
    job_id = add_job(store)
    stage = FakeStage("one")
    assert execute_job(job_id, store, settings, stages=[stage]) == "succeeded"
    assert execute_job(job_id, store, settings, stages=[stage]) == "skipped"
    assert stage.runs == 1


def test_claim_is_exclusive_until_the_lease_expires(store):
    job_id = add_job(store)
    lease = timedelta(seconds=60)
    assert store.claim_job(job_id, "w1", lease) is not None
    assert store.claim_job(job_id, "w2", lease) is None
    assert store.claim_job(job_id, "w2", timedelta(0)) is not None  # stale: taken over
    assert store.get_job(job_id).worker == "w2"


def test_worker_whose_job_was_taken_over_stops_without_writing(store, settings):
    job_id = add_job(store)
    events = []

    def taken_over(i):
        if i == 1:
            assert store.requeue_stale(timedelta(0)) == [job_id]
            assert store.claim_job(job_id, "new-worker", timedelta(seconds=60)) is not None
            events.append(i)

    stage = FakeStage("one", steps=5, on_step=taken_over)
    assert execute_job(job_id, store, settings, stages=[stage]) == "lost"
    job = store.get_job(job_id)
    assert job.status == "running" and job.worker == "new-worker"
    assert not (JobPaths(settings.storage_dir, job_id).output / "one").exists()


def test_unexpected_error_shows_clients_an_error_id_not_paths_or_urls(tmp_path, scene, caplog):
    """Defect 4: "Job errors carry raw exception text (storage paths, broker URLs)"."""
    settings = make_settings(tmp_path)
    secret = f"cannot write {settings.storage_dir.resolve()}/jobs/x via redis://:pw@10.0.0.5:6379/0"
    with TestClient(create_app(settings)) as client:
        upload = client.post("/v1/uploads", content=tar_bytes(scene), headers={**AUTH_A, **TAR})
        body = {"upload_id": upload.json()["id"]}
        job_id = client.post("/v1/jobs", json=body, headers=AUTH_A).json()["id"]
        stage = FakeStage("one", fail=RuntimeError(secret))
        with caplog.at_level(logging.ERROR, logger="worker.execute"):
            status = execute_job(job_id, state_of(client).store, settings, stages=[stage])
        assert status == "failed"
        shown = client.get(f"/v1/jobs/{job_id}", headers=AUTH_A)
        events = client.get(f"/v1/jobs/{job_id}/events", headers=AUTH_A)
    error = shown.json()["error"]
    for text in (shown.text, events.text):
        assert str(tmp_path) not in text and "redis://" not in text and "Traceback" not in text
    assert error["type"] == "internal" and error["error_id"] in error["detail"]
    logged = [r for r in caplog.records if error["error_id"] in r.getMessage()]
    assert logged and logged[0].exc_info is not None  # the full traceback stays server-side
    assert secret in str(logged[0].exc_info[1])
