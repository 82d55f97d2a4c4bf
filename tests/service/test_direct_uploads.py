"""Presigned multipart uploads straight to object storage (``/v1/direct-uploads``), validated
by the API after completion, against a real S3 server (tests/s3server.py)."""

from __future__ import annotations

import hashlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from jobstore.s3 import S3Storage
from service.main import create_app
from tests.s3server import S3Server, s3_settings
from tests.service.conftest import AUTH_A, TestClient, assert_problem, make_settings, state_of

pytestmark = pytest.mark.integration

MIB = 2**20


@pytest.fixture
def client(s3_server: S3Server, tmp_path: Path) -> Iterator[TestClient]:
    settings = s3_settings(
        s3_server, tmp_path, max_upload_bytes=16 * MIB, direct_upload_part_bytes=5 * MIB
    )
    with TestClient(create_app(settings)) as test_client:
        yield test_client


def _start(client: TestClient, data: bytes, **fields: Any) -> dict[str, Any]:
    body = {"content_type": "application/x-tar", "size": len(data), **fields}
    response = client.post("/v1/direct-uploads", json=body, headers=AUTH_A)
    assert response.status_code == 201, response.text
    started: dict[str, Any] = response.json()
    return started


def _put_parts(started: dict[str, Any], data: bytes) -> list[dict[str, Any]]:
    size = started["part_size"]
    done = []
    for part in started["parts"]:
        n = part["part_number"]
        chunk = data[(n - 1) * size : n * size]
        response = httpx.put(part["url"], content=chunk)
        assert response.status_code == 200, response.text
        done.append({"part_number": n, "etag": response.headers["etag"]})
    return done


def _leftovers(client: TestClient) -> list[str]:
    storage = state_of(client).storage
    assert isinstance(storage, S3Storage)
    return [o["Key"] for o in storage.objects(storage.prefix) if "/direct-uploads/" in o["Key"]]


def test_a_multipart_upload_becomes_a_validated_upload(client, scene_tar):
    data = scene_tar + bytes(6 * MIB)  # zero blocks after the end of a tar are allowed
    started = _start(client, data, sha256=hashlib.sha256(data).hexdigest())
    assert len(started["parts"]) == 2 and started["part_size"] == 5 * MIB
    parts = _put_parts(started, data)
    response = client.post(started["links"]["complete"], json={"parts": parts}, headers=AUTH_A)
    assert response.status_code == 201, response.text
    upload = response.json()
    assert upload["id"] == started["id"] and upload["size"] == len(data)
    assert upload["sha256"] == hashlib.sha256(data).hexdigest()
    assert upload["summary"]["capture"]["frames"] > 0
    assert client.get(f"/v1/uploads/{upload['id']}", headers=AUTH_A).status_code == 200
    job = client.post("/v1/jobs", json={"upload_id": upload["id"]}, headers=AUTH_A)
    assert job.status_code == 202, job.text
    assert _leftovers(client) == []
    again = client.post(started["links"]["complete"], json={"parts": parts}, headers=AUTH_A)
    assert_problem(again, 404)


def test_a_digest_mismatch_keeps_nothing(client, scene_tar):
    started = _start(client, scene_tar, sha256="0" * 64)
    parts = _put_parts(started, scene_tar)
    response = client.post(started["links"]["complete"], json={"parts": parts}, headers=AUTH_A)
    assert assert_problem(response, 422)["type"].endswith("digest-mismatch")
    assert client.get(f"/v1/uploads/{started['id']}", headers=AUTH_A).status_code == 404
    assert _leftovers(client) == []


def test_an_invalid_archive_is_refused_like_a_normal_upload(client):
    data = b"this is not an archive" * 100
    started = _start(client, data)
    parts = _put_parts(started, data)
    response = client.post(started["links"]["complete"], json={"parts": parts}, headers=AUTH_A)
    body = assert_problem(response, 422)
    assert body["type"].endswith("invalid-upload") and body["errors"]
    assert _leftovers(client) == []


def test_refused_parts_can_be_completed_again(client, scene_tar):
    started = _start(client, scene_tar)
    parts = _put_parts(started, scene_tar)
    wrong = [{"part_number": 1, "etag": '"0123456789abcdef0123456789abcdef"'}]
    response = client.post(started["links"]["complete"], json={"parts": wrong}, headers=AUTH_A)
    body = assert_problem(response, 422)
    assert body["type"].endswith("invalid-parts") and body["errors"][0]["path"] == "body.parts"
    response = client.post(started["links"]["complete"], json={"parts": parts}, headers=AUTH_A)
    assert response.status_code == 201, response.text


def test_bad_requests_name_the_field(client):
    too_big = {"content_type": "application/x-tar", "size": 17 * MIB}
    assert_problem(client.post("/v1/direct-uploads", json=too_big, headers=AUTH_A), 413)
    bad_type = {"content_type": "text/plain", "size": 10}
    body = assert_problem(client.post("/v1/direct-uploads", json=bad_type, headers=AUTH_A), 422)
    assert body["errors"][0]["path"] == "body.content_type"
    bad_digest = {"content_type": "application/zip", "size": 10, "sha256": "xyz"}
    body = assert_problem(client.post("/v1/direct-uploads", json=bad_digest, headers=AUTH_A), 422)
    assert body["errors"][0]["path"] == "body.sha256"
    parts = {"parts": [{"part_number": 1, "etag": "x"}]}
    assert_problem(client.post("/v1/direct-uploads/nope:complete", json=parts, headers=AUTH_A), 404)


def test_local_storage_answers_409(tmp_path):
    with TestClient(create_app(make_settings(tmp_path))) as client:
        body = {"content_type": "application/x-tar", "size": 10}
        problem = assert_problem(client.post("/v1/direct-uploads", json=body, headers=AUTH_A), 409)
        assert problem["type"].endswith("direct-uploads-unavailable")
        assert "DCSEG_STORAGE_BACKEND" in problem["detail"]
        parts = {"parts": [{"part_number": 1, "etag": "x"}]}
        response = client.post("/v1/direct-uploads/x:complete", json=parts, headers=AUTH_A)
        assert_problem(response, 409)
