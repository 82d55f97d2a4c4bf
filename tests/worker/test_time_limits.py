"""Stage time limits (``DCSEG_STAGE_TIME_LIMIT_S``) in every worker mode: a stage over its
limit fails the job naming stage, limit and setting; one that never reports progress is
abandoned (thread mode) or its process killed (embedded process, Celery prefork child)."""

from __future__ import annotations

import threading
import time

from jobstore.contract import JobPaths
from jobstore.settings import Settings
from tests.service.conftest import wait_for as wait_until
from tests.worker.conftest import add_job
from tests.worker.fakes import FakeStage, SilentStage, stuck_stages
from worker.execute import execute_job, read_manifest
from worker.local import EmbeddedWorker
from worker.stage import Stage
from worker.stages import default_stages


def _limited(settings: Settings, limits: dict[str, float], grace: float = 0.3) -> Settings:
    update = {"stage_time_limit_s": limits, "stage_kill_grace_s": grace}
    return settings.model_copy(update=update)


def _timeout_detail(stage: str, limit: str) -> str:
    return f"stage {stage} exceeded its time limit of {limit} s (setting DCSEG_STAGE_TIME_LIMIT_S)"


def test_every_default_stage_has_a_time_limit():
    """Defect 1: "time limits for every stage": validate, reconstruct, train and segment."""
    limits = Settings().stage_time_limit_s
    for stage in default_stages():
        assert limits.get(stage.name, 0) > 0, stage.name
    assert Settings().stage_time_limit_default_s > 0  # stages without an entry


def test_stage_past_its_time_limit_fails_the_job_naming_stage_limit_and_setting(store, settings):
    """Defect 1: a stage over its limit fails with "stage X exceeded its time limit of N s"."""
    job_id = add_job(store)
    stage = FakeStage("slow", steps=20, on_step=lambda i: time.sleep(0.03))
    assert execute_job(job_id, store, _limited(settings, {"slow": 0.1}), stages=[stage]) == "failed"
    error = store.get_job(job_id).error
    assert error["type"] == "timeout" and error["detail"] == _timeout_detail("slow", "0.1")


def test_stage_that_never_reports_progress_fails_at_its_limit_in_thread_mode(store, settings):
    """Defect 1: a stage stuck without progress calls must still be stopped (thread mode: the
    job fails and the stage is abandoned; nothing it writes later is kept)."""
    job_id = add_job(store)
    release = threading.Event()
    stages: list[Stage] = [FakeStage("validate"), SilentStage("stuck", release=release)]
    limited = _limited(settings, {"stuck": 0.2})
    result: list[str] = []
    runner = threading.Thread(
        target=lambda: result.append(execute_job(job_id, store, limited, stages=stages))
    )
    runner.start()
    try:
        wait_until(lambda: store.get_job(job_id).status == "failed", timeout=30)
    finally:
        release.set()
        runner.join(30)
    error = store.get_job(job_id).error
    assert error["type"] == "timeout" and error["detail"] == _timeout_detail("stuck", "0.2")
    assert result == ["failed"]
    paths = JobPaths(settings.storage_dir, job_id)
    assert [s["name"] for s in read_manifest(paths)["stages"]] == ["validate"]
    assert not (paths.output / "stuck").exists()


def test_stage_that_never_reports_progress_is_killed_in_process_mode(store, settings):
    """Defect 1: in process mode a stage stuck in native code is stopped by killing the worker
    child; the job fails with the time-limit error instead of hanging forever."""
    job_id = add_job(store)
    worker = EmbeddedWorker(_limited(settings, {"stuck": 0.5}), mode="process", stages=stuck_stages)
    worker.start()
    try:
        wait_until(lambda: store.get_job(job_id).status == "failed", timeout=60)
        wait_until(lambda: not worker.alive(), timeout=30)  # the stuck child was killed
        worker.ensure_running()
        assert worker.alive()
    finally:
        worker.stop()
    error = store.get_job(job_id).error
    assert error["type"] == "timeout" and error["detail"] == _timeout_detail("stuck", "0.5")
