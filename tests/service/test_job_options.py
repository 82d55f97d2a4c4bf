"""Job options (``POST /v1/jobs``): absurd, non-finite and unknown options answer 422 naming
the field, through the config builder the CLI and the worker use; stored overrides hold
only what was given."""

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
        ({"capture": {"distortion": [0.1] * 17}}, "options.capture.distortion"),
        ({"capture": {"distortion": "barrel"}}, "options.capture.distortion"),
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


@pytest.mark.parametrize(
    ("capture", "reason"),
    [
        ({"distortion": [0.1, 0, 0, 0]}, "distortion is the lens of intrinsics"),
        ({"intrinsics": [500, 500, 320, 240], "distortion": [0.1, 0.2, 0.3]}, "4, 5 or 8"),
    ],
)
def test_lens_distortion_checked_with_its_intrinsics(client, upload_id, queue, capture, reason):
    body = assert_problem(_post(client, upload_id, {"capture": capture}), 422)
    assert body["errors"][0]["path"] == "body.options.capture"
    assert reason in body["errors"][0]["reason"]
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
