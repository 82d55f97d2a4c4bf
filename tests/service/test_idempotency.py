"""``Idempotency-Key`` (:mod:`service.idempotency`) on uploads and jobs: replays, a key in
flight answers 409, and records expire and are swept."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from datetime import timedelta

from sqlalchemy import func, select, update

from jobstore.models import IdempotencyKey, Upload, utcnow
from service import uploads as service_uploads
from tests.service.conftest import (
    AUTH_A,
    assert_problem,
    state_of,
    wait_for,
)
from tests.service.test_upload_limits import BOUND_S, _Gate, _upload


def test_upload_honours_idempotency_key(client, scene_tar, scene):
    """Defect: "uploads ignore Idempotency-Key"; same key + body replays, another body 422."""
    first = _upload(client, scene_tar, **{"Idempotency-Key": "up-1"})
    assert first.status_code == 201, first.text
    again = _upload(client, scene_tar, **{"Idempotency-Key": "up-1"})
    assert again.status_code == 201 and again.json() == first.json()
    assert again.headers["idempotent-replayed"] == "true"
    assert again.headers["location"] == first.headers["location"]
    other = scene_tar + b"\0" * 1024  # tar padding: a different body of the same capture
    body = assert_problem(_upload(client, other, **{"Idempotency-Key": "up-1"}), 422)
    assert body["type"].endswith("idempotency-mismatch")
    with state_of(client).store.session() as s:
        assert s.scalar(select(func.count()).select_from(Upload)) == 1
    uploads_dir = state_of(client).settings.storage_dir / "uploads"
    assert [p.name for p in uploads_dir.iterdir()] == [first.json()["id"]]


def test_upload_with_a_key_in_flight_answers_409(client, scene_tar, monkeypatch):
    """Defect: uploads honour Idempotency-Key as jobs do: the same key while the first
    request is still validating answers 409, and the first one still succeeds."""
    gate = _Gate()
    monkeypatch.setattr(service_uploads, "extract_and_validate", gate)
    key = {"Idempotency-Key": "slow"}
    with ThreadPoolExecutor(1) as pool:
        first = pool.submit(_upload, client, scene_tar, **key)
        try:
            wait_for(lambda: gate.entered == 1, timeout=BOUND_S)
            second = _upload(client, scene_tar, **key)
        finally:
            gate.release.set()
        assert first.result(timeout=BOUND_S).status_code == 201
    assert assert_problem(second, 409)["type"].endswith("idempotency-in-flight")


def test_idempotency_keys_older_than_the_ttl_are_ignored_and_swept(make_client, scene_tar):
    """Defect: "Idempotency records never expire"; past the TTL a key is new again and the
    periodic sweep deletes the record."""
    client = make_client(idempotency_ttl_s=3600.0, housekeeping_interval_s=3600.0)
    upload = _upload(client, scene_tar).json()["id"]
    key = {**AUTH_A, "Idempotency-Key": "job-1"}
    first = client.post("/v1/jobs", json={"upload_id": upload}, headers=key)
    assert first.status_code == 202, first.text
    client.post(f"/v1/jobs/{first.json()['id']}:cancel", headers=AUTH_A)
    store = state_of(client).store
    with store.session() as s:
        s.execute(update(IdempotencyKey).values(created_at=utcnow() - timedelta(hours=2)))
    second = client.post("/v1/jobs", json={"upload_id": upload, "preset": "paper"}, headers=key)
    assert second.status_code == 202, second.text  # not 422: the old record has expired
    assert second.json()["id"] != first.json()["id"]
    with store.session() as s:
        s.execute(update(IdempotencyKey).values(created_at=utcnow() - timedelta(hours=2)))
    assert store.idempotency_sweep(timedelta(hours=1)) == 1
    with store.session() as s:
        assert s.scalar(select(func.count()).select_from(IdempotencyKey)) == 0


def test_housekeeping_sweeps_expired_idempotency_records(make_client, scene_tar):
    """Defect: "Idempotency records never expire"; the periodic sweep deletes old ones."""
    client = make_client(idempotency_ttl_s=3600.0, housekeeping_interval_s=0.05)
    response = _upload(client, scene_tar, **{"Idempotency-Key": "old"})
    assert response.status_code == 201
    store = state_of(client).store
    with store.session() as s:
        assert s.scalar(select(func.count()).select_from(IdempotencyKey)) == 1
        s.execute(update(IdempotencyKey).values(created_at=utcnow() - timedelta(hours=2)))

    def swept() -> bool:
        with store.session() as s:
            return s.scalar(select(func.count()).select_from(IdempotencyKey)) == 0

    wait_for(swept, timeout=BOUND_S)
