"""Issue 17, typed job options: ``POST /v1/jobs`` refuses absurd, non-finite and unknown
options with 422 naming the field, through the config builder the CLI and the worker use."""

from __future__ import annotations

from typing import Any

import pytest

from tests.service.conftest import AUTH_A, assert_problem, state_of
from tests.worker.fakes import RecordingQueue


@pytest.fixture
def queue(client) -> RecordingQueue:
    recording = RecordingQueue()
    state_of(client).queue = recording
    return recording


def _post(client: Any, upload_id: str, options: dict[str, Any]) -> Any:
    return client.post(
        "/v1/jobs", json={"upload_id": upload_id, "options": options}, headers=AUTH_A
    )


def _paths(response: Any) -> list[str]:
    body = assert_problem(response, 422)
    return [item["path"] for item in body["errors"]]


@pytest.mark.parametrize(
    ("options", "field"),
    [
        ({"capture": {"size": [60000, 60000]}}, "options.capture.size"),
        ({"affinity": {"iterations": 1_000_000_000}}, "options.affinity.iterations"),
        ({"reconstruct": {"iterations": 10**9}}, "options.reconstruct.iterations"),
        ({"reconstruct": {"max_gaussians": 10**12}}, "options.reconstruct.max_gaussians"),
        ({"reconstruct": {"bogus": 1}}, "options.reconstruct.bogus"),
        ({"capture": {"stride": 0}}, "options.capture.stride"),
        ({"budget": {"max_side": 4}}, "options.budget.max_side"),
        ({"budget": {"max_side": "huge"}}, "options.budget.max_side"),
        ({"budget": {"max_keyframes": 10**9}}, "options.budget.max_keyframes"),
        ({"budget": {"min_rotation_deg": 720}}, "options.budget.min_rotation_deg"),
    ],
)
def test_job_options_out_of_bounds_answer_422_naming_the_field(
    client, upload_id, queue, options, field
):
    """Job options are untyped dicts checked only for lower bounds in the worker."""
    paths = _paths(_post(client, upload_id, options))
    assert any(p.startswith(f"body.{field}") for p in paths), paths
    assert queue.job_ids == []


@pytest.mark.parametrize("literal", ["Infinity", "-Infinity", "NaN"])
def test_non_finite_options_answer_422(client, upload_id, queue, literal):
    """`Infinity`/`NaN` in options are accepted and silently stored as `null`."""
    raw = (
        f'{{"upload_id": "{upload_id}", "options": {{"capture": {{"depth_trunc": {literal}}}, '
        f'"reconstruct": {{"depth_weight": {literal}}}}}}}'
    )
    response = client.post(
        "/v1/jobs", content=raw, headers={**AUTH_A, "Content-Type": "application/json"}
    )
    paths = _paths(response)
    assert "body.options.capture.depth_trunc" in paths
    assert "body.options.reconstruct.depth_weight" in paths
    assert queue.job_ids == []


def test_cross_field_rules_of_the_stage_configs_answer_422(client, upload_id, queue):
    """The API refuses what the worker's config builder would (knn_sample <= knn_k)."""
    response = _post(client, upload_id, {"affinity": {"knn_k": 4, "knn_sample": 8}})
    body = assert_problem(response, 422)
    assert body["errors"][0]["path"] == "body.options.affinity"
    assert "knn_sample (8) must be at most knn_k (4)" in body["errors"][0]["reason"]
    assert queue.job_ids == []


def test_no_upscaling_beyond_the_uploaded_capture(client, upload_id, queue):
    """A target size above the upload's frames is refused (frames are only downscaled)."""
    upload = client.get(f"/v1/uploads/{upload_id}", headers=AUTH_A).json()
    width, height = (int(v) for v in upload["summary"]["capture"]["resolution"][0].split("x"))
    bigger = _post(client, upload_id, {"capture": {"size": [width * 2, height * 2]}})
    assert _paths(bigger) == ["body.options.capture.size"]
    same = _post(client, upload_id, {"capture": {"size": [width, height]}})
    assert same.status_code == 202, same.text
    assert same.json()["config"]["options"]["capture"]["size"] == [width, height]


def test_stored_overrides_hold_only_the_given_fields(client, upload_id, queue):
    response = _post(client, upload_id, {"reconstruct": {"voxel_size": None, "iterations": 3}})
    assert response.status_code == 202, response.text
    stored = response.json()["config"]["options"]
    assert stored["reconstruct"] == {"voxel_size": None, "iterations": 3}
    assert stored["affinity"] == {}


def test_queue_failure_error_carries_no_broker_text(client, upload_id, queue, monkeypatch):
    """Job errors carry raw exception text (storage paths, broker URLs): the enqueue failure
    too. The failed job's error has a type and an error id, not the exception's text."""

    def broken(job_id: str) -> None:
        raise ConnectionError("Error 111 connecting to redis://:s3cret@10.0.0.7:6379/0")

    monkeypatch.setattr(state_of(client).queue, "enqueue", broken)
    assert_problem(_post(client, upload_id, {}), 503)
    job = client.get("/v1/jobs", headers=AUTH_A).json()["jobs"][0]
    assert job["status"] == "failed" and job["error"]["type"] == "queue-unavailable"
    assert job["error"]["error_id"] in job["error"]["detail"]
    assert "redis" not in str(job["error"]) and "s3cret" not in str(job["error"])


def test_in_flight_idempotency_window_is_a_setting(tmp_path):
    """Upload idempotency: a request still in flight blocked its key for a hard-coded 2 min
    (shorter than validating a large upload); the window is DCSEG_IDEMPOTENCY_IN_FLIGHT_S."""
    from datetime import timedelta

    from jobstore.store import Store

    store = Store(f"sqlite:///{tmp_path / 'db.sqlite'}")
    store.init_schema()
    store.ensure_tenant("t")
    assert store.idempotency_begin("t", "k", "h").kind == "new"
    long = timedelta(hours=2)
    assert store.idempotency_begin("t", "k", "h", in_flight=long).kind == "in_flight"
    assert store.idempotency_begin("t", "k", "h", in_flight=timedelta(0)).kind == "new"
    assert store.idempotency_begin("t", "k", "h").kind == "in_flight"  # the default is 1 h
    store.close()


def test_time_limit_settings_must_fit_together():
    """Stage time limits must be positive and fit in the Celery task limit (the defaults added
    up to 9.25 h against a 6 h soft limit), and soft < hard < visibility timeout."""
    from pydantic import ValidationError

    from jobstore.settings import Settings

    defaults = Settings()
    assert sum(defaults.stage_time_limit_s.values()) <= defaults.task_soft_time_limit_s
    with pytest.raises(ValidationError, match="must be > 0"):
        Settings(stage_time_limit_s={"train": 0})
    with pytest.raises(ValidationError, match="add up to"):
        Settings(stage_time_limit_s={"train": 9 * 3600, "segment": 2 * 3600})
    with pytest.raises(ValidationError, match="DCSEG_VISIBILITY_TIMEOUT_S"):
        Settings(task_time_limit_s=13 * 3600)
