"""``POST /v1/uploads``: happy paths, and every bad input answering problem+json with nothing
left behind."""

from __future__ import annotations

import base64
import hashlib
import io
import tarfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import pytest
from sqlalchemy import func, select

from jobstore.models import IdempotencyKey, Job, Upload
from service import uploads as service_uploads
from tests.service.conftest import (
    AUTH_A,
    AUTH_B,
    TAR,
    assert_problem,
    state_of,
    tar_bytes,
    zip_bytes,
)


def _nothing_stored(client) -> None:
    state = state_of(client)
    uploads = state.settings.storage_dir / "uploads"
    assert not uploads.exists() or list(uploads.iterdir()) == []
    with state.store.session() as s:
        assert s.scalar(select(func.count()).select_from(Upload)) == 0


def test_tar_upload_is_validated_and_summarised(client, scene_tar):
    digest = hashlib.sha256(scene_tar).hexdigest()
    response = client.post("/v1/uploads", content=scene_tar, headers={**AUTH_A, **TAR})
    assert response.status_code == 201, response.text
    body = response.json()
    assert body["sha256"] == digest and body["size"] == len(scene_tar)
    assert body["summary"]["capture"]["frames"] == 4
    assert body["summary"]["inputs"] == {
        "agnostic_masks": "masks/agnostic",
        "semantic_masks": "masks/semantic",
        "vocabulary": "vocabulary.txt",
        "ground_truth": "gt/points.ply",
    }
    assert response.headers["location"] == f"/v1/uploads/{body['id']}"
    again = client.get(body["links"]["self"], headers=AUTH_A)
    assert again.status_code == 200 and again.json() == body
    assert_problem(client.get(body["links"]["self"], headers=AUTH_B), 404)


def test_zip_with_top_folder_and_digest_header(client, scene):
    data = zip_bytes(scene, top="my-scan/")
    b64 = base64.b64encode(hashlib.sha256(data).digest()).decode()
    headers = {**AUTH_A, "Content-Type": "application/zip", "Repr-Digest": f"sha-256=:{b64}:"}
    response = client.post("/v1/uploads", content=data, headers=headers)
    assert response.status_code == 201, response.text
    assert response.json()["summary"]["root"] == "my-scan"


def test_gzip_tar_with_sha256_query(client, scene):
    data = tar_bytes(scene, mode="w:gz")
    digest = hashlib.sha256(data).hexdigest()
    response = client.post(
        f"/v1/uploads?sha256={digest}",
        content=data,
        headers={**AUTH_A, "Content-Type": "application/gzip"},
    )
    assert response.status_code == 201, response.text


def test_digest_mismatch(client, scene_tar):
    wrong = hashlib.sha256(b"other").hexdigest()
    response = client.post(
        f"/v1/uploads?sha256={wrong}", content=scene_tar, headers={**AUTH_A, **TAR}
    )
    assert assert_problem(response, 422)["type"].endswith("digest-mismatch")
    _nothing_stored(client)


def test_malformed_digest_header(client, scene_tar):
    headers = {**AUTH_A, **TAR, "Repr-Digest": "md5=:abc:"}
    assert_problem(client.post("/v1/uploads", content=scene_tar, headers=headers), 400)
    _nothing_stored(client)


@pytest.mark.parametrize("content_type", ["application/json", "text/plain", None])
def test_wrong_content_type(client, scene_tar, content_type):
    headers = dict(AUTH_A)
    if content_type:
        headers["Content-Type"] = content_type
    assert_problem(client.post("/v1/uploads", content=scene_tar, headers=headers), 415)
    _nothing_stored(client)


def test_oversize_by_content_length(client, settings):
    body = b"\0" * (settings.max_upload_bytes + 1)
    assert_problem(client.post("/v1/uploads", content=body, headers={**AUTH_A, **TAR}), 413)
    _nothing_stored(client)


def test_oversize_streamed_without_length(client, settings):
    def chunks() -> Iterator[bytes]:
        for _ in range(settings.max_upload_bytes // 2**16 + 2):
            yield b"\0" * 2**16

    response = client.post("/v1/uploads", content=chunks(), headers={**AUTH_A, **TAR})
    assert_problem(response, 413)
    _nothing_stored(client)


def test_corrupt_archive(client, scene_tar):
    broken = scene_tar[: len(scene_tar) // 3] + b"garbage" * 100
    body = assert_problem(
        client.post("/v1/uploads", content=broken, headers={**AUTH_A, **TAR}), 422
    )
    assert body["errors"], body
    _nothing_stored(client)


def test_not_an_archive(client):
    response = client.post("/v1/uploads", content=b"hello" * 100, headers={**AUTH_A, **TAR})
    body = assert_problem(response, 422)
    assert body["errors"][0]["path"] == "upload"
    _nothing_stored(client)


def test_traversal_entry(client, scene, tmp_path):
    def evil(tf: tarfile.TarFile) -> None:
        info = tarfile.TarInfo("../../escape.txt")
        info.size = 4
        tf.addfile(info, io.BytesIO(b"evil"))

    response = client.post(
        "/v1/uploads", content=tar_bytes(scene, extra=evil), headers={**AUTH_A, **TAR}
    )
    body = assert_problem(response, 422)
    assert "escape" in body["detail"]
    assert not (state_of(client).settings.storage_dir.parent / "escape.txt").exists()
    _nothing_stored(client)


def test_symlink_entry(client, scene):
    def link(tf: tarfile.TarFile) -> None:
        info = tarfile.TarInfo("passwd")
        info.type = tarfile.SYMTYPE
        info.linkname = "/etc/passwd"
        tf.addfile(info)

    response = client.post(
        "/v1/uploads", content=tar_bytes(scene, extra=link), headers={**AUTH_A, **TAR}
    )
    assert "link" in assert_problem(response, 422)["detail"]
    _nothing_stored(client)


def test_missing_frame_names_the_file(client, scene_copy):
    rgb = sorted((scene_copy / "rgb").iterdir())[1]
    rgb.unlink()
    response = client.post("/v1/uploads", content=tar_bytes(scene_copy), headers={**AUTH_A, **TAR})
    body = assert_problem(response, 422)
    paths = [e["path"] for e in body["errors"]]
    assert any(rgb.name in p or "capture.json" in p for p in paths), body
    assert all(not p.startswith("/") for p in paths), "server paths must not leak"
    _nothing_stored(client)


def test_mismatched_mask_size_names_the_frame(client, scene_copy):
    mask = sorted((scene_copy / "masks" / "semantic").iterdir())[0]
    image = cv2.imread(str(mask), cv2.IMREAD_UNCHANGED)
    assert image is not None
    cv2.imwrite(str(mask), cv2.resize(image, (64, 64), interpolation=cv2.INTER_NEAREST))
    response = client.post("/v1/uploads", content=tar_bytes(scene_copy), headers={**AUTH_A, **TAR})
    body = assert_problem(response, 422)
    assert any(mask.stem in e["path"] or mask.stem in e["reason"] for e in body["errors"]), body
    _nothing_stored(client)


def test_empty_archive(client, tmp_path: Path):
    (tmp_path / "empty").mkdir()
    response = client.post(
        "/v1/uploads", content=tar_bytes(tmp_path / "empty"), headers={**AUTH_A, **TAR}
    )
    assert_problem(response, 422)
    _nothing_stored(client)


@pytest.mark.parametrize(
    "headers", [{}, {"Authorization": "Bearer nope"}, {"Authorization": "Basic x"}]
)
def test_missing_or_wrong_auth(client, scene_tar, headers):
    response = client.post("/v1/uploads", content=scene_tar, headers={**headers, **TAR})
    assert_problem(response, 401)
    assert response.headers["www-authenticate"].startswith("Bearer")
    _nothing_stored(client)


def test_delete_upload(client, upload_id):
    job = client.post("/v1/jobs", json={"upload_id": upload_id}, headers=AUTH_A).json()
    assert_problem(client.delete(f"/v1/uploads/{upload_id}", headers=AUTH_B), 404)
    assert_problem(client.delete(f"/v1/uploads/{upload_id}", headers=AUTH_A), 409)
    assert client.post(f"/v1/jobs/{job['id']}:cancel", headers=AUTH_A).status_code == 200
    assert client.delete(f"/v1/jobs/{job['id']}", headers=AUTH_A).status_code == 204
    assert client.delete(f"/v1/uploads/{upload_id}", headers=AUTH_A).status_code == 204
    _nothing_stored(client)
    assert_problem(client.get(f"/v1/uploads/{upload_id}", headers=AUTH_A), 404)


def test_digests_separate_capture_from_masks(client, scene_tar, scene_copy):
    first = client.post("/v1/uploads", content=scene_tar, headers={**AUTH_A, **TAR}).json()
    mask = sorted((scene_copy / "masks" / "semantic").iterdir())[0]
    image = cv2.imread(str(mask), cv2.IMREAD_UNCHANGED)
    assert image is not None
    cv2.imwrite(str(mask), image[::-1].copy())  # new class-aware masks, same capture
    second = client.post("/v1/uploads", content=tar_bytes(scene_copy), headers={**AUTH_A, **TAR})
    a, b = first["summary"]["digests"], second.json()["summary"]["digests"]
    assert set(a) == {"capture", "agnostic_masks", "semantic_masks", "vocabulary", "ground_truth"}
    assert a["capture"] == b["capture"] and a["agnostic_masks"] == b["agnostic_masks"]
    assert a["semantic_masks"] != b["semantic_masks"]
    from dcseg.stages import RECONSTRUCT, VALIDATE
    from worker.stages import LibraryStage

    config_a = {"preset": "fast", "options": {}, "inputs": a}
    config_b = {"preset": "fast", "options": {}, "inputs": b}
    reconstruct, validate = LibraryStage(RECONSTRUCT), LibraryStage(VALIDATE)
    assert reconstruct.key(config_a) == reconstruct.key(config_b)  # reused
    assert validate.key(config_a) != validate.key(config_b)  # re-checked


def test_upload_deleted_while_a_job_is_created_answers_404_not_500(client, upload_id, monkeypatch):
    """Defect: "deleting an upload while a job is created answers 500"; the delete lands
    between the job's upload check and its insert: a precise 404, nothing half-made."""
    state = state_of(client)
    real_create = state.store.create_job

    def delete_first(job: Job, **kwargs: Any) -> Job:
        assert state.store.delete_upload(upload_id, "tenant-a") is not None
        service_uploads.remove(state.settings.storage_dir / "uploads" / upload_id)
        return real_create(job, **kwargs)

    monkeypatch.setattr(state.store, "create_job", delete_first)
    response = client.post(
        "/v1/jobs", json={"upload_id": upload_id}, headers={**AUTH_A, "Idempotency-Key": "k"}
    )
    body = assert_problem(response, 404)
    assert upload_id in body["detail"]
    with state.store.session() as s:
        assert s.scalar(select(func.count()).select_from(Job)) == 0
        assert s.scalar(select(func.count()).select_from(IdempotencyKey)) == 0
    assert client.get(f"/v1/uploads/{upload_id}", headers=AUTH_A).status_code == 404
