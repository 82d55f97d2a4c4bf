"""Artifact downloads (:mod:`service.artifacts`) as RFC 9110 says: huge Range numbers, the range
unit's case, ``If-None-Match`` with ``*`` and weak tags, and ``HEAD``."""

from __future__ import annotations

import hashlib

import pytest

from service.artifacts import parse_range
from tests.service.conftest import AUTH_A, assert_problem, state_of
from tests.worker.fakes import FakeStage
from worker.execute import execute_job

BLOB = bytes(range(256)) * 40  # 10240 bytes
HUGE = "9" * 5000
"""More digits than Python's ``int()`` converts by default (4300): it raised, answering 500."""


@pytest.fixture
def url(client, upload_id) -> str:
    """The download URL of a 10240-byte artifact of a finished job."""
    state = state_of(client)
    created = client.post("/v1/jobs", json={"upload_id": upload_id}, headers=AUTH_A)
    job_id: str = created.json()["id"]
    stages = [FakeStage("two", files={"scene.ply": BLOB})]
    assert execute_job(job_id, state.store, state.settings, stages=stages) == "succeeded"
    return f"/v1/jobs/{job_id}/artifacts/two/scene.ply"


def test_range_with_a_huge_first_position_is_unsatisfiable(client, url):
    """`Range: bytes=<5000 digits>-` answers 500."""
    response = client.get(url, headers={**AUTH_A, "Range": f"bytes={HUGE}-"})
    body = assert_problem(response, 416)
    assert response.headers["content-range"] == f"bytes */{len(BLOB)}"
    assert str(len(BLOB)) in body["detail"]


def test_range_with_huge_last_or_suffix_length_is_clamped_to_the_file(client, url):
    """`Range: bytes=<5000 digits>-` answers 500 (last-pos and suffix-length alike)."""
    last = client.get(url, headers={**AUTH_A, "Range": f"bytes=10-{HUGE}"})
    assert last.status_code == 206 and last.content == BLOB[10:]
    assert last.headers["content-range"] == f"bytes 10-{len(BLOB) - 1}/{len(BLOB)}"
    suffix = client.get(url, headers={**AUTH_A, "Range": f"bytes=-{HUGE}"})
    assert suffix.status_code == 206 and suffix.content == BLOB
    padded = client.get(url, headers={**AUTH_A, "Range": f"bytes={'0' * 5000}5-9"})
    assert padded.status_code == 206 and padded.content == BLOB[5:10]
    backwards = client.get(url, headers={**AUTH_A, "Range": f"bytes={HUGE}0-{HUGE}"})
    assert backwards.status_code == 200 and backwards.content == BLOB


def test_parse_range_never_converts_an_unbounded_number():
    """`Range: bytes=<5000 digits>-` answers 500 (the parser itself)."""
    assert parse_range(f"bytes=0-{HUGE}", 10) == (0, 9)
    assert parse_range(f"bytes=-{HUGE}", 10) == (0, 9)
    assert parse_range("bytes=00000000000000000000000000003-4", 10) == (3, 4)


def test_range_unit_is_case_insensitive(client, url):
    """The unit is case-sensitive."""
    for unit in ("BYTES", "Bytes", "bYtEs"):
        response = client.get(url, headers={**AUTH_A, "Range": f"{unit}=100-199"})
        assert response.status_code == 206, unit
        assert response.content == BLOB[100:200]
        assert response.headers["content-range"] == f"bytes 100-199/{len(BLOB)}"


def test_if_none_match_star_matches_the_existing_artifact(client, url):
    """If-None-Match ignores `*`."""
    response = client.get(url, headers={**AUTH_A, "If-None-Match": "*"})
    assert response.status_code == 304 and response.content == b""
    assert response.headers["etag"] == f'"{hashlib.sha256(BLOB).hexdigest()}"'


def test_if_none_match_uses_weak_comparison(client, url):
    """If-None-Match ignores `W/`."""
    tag = f'"{hashlib.sha256(BLOB).hexdigest()}"'
    for header in (f"W/{tag}", f'"other", W/{tag}', f'W/"other",{tag}'):
        response = client.get(url, headers={**AUTH_A, "If-None-Match": header})
        assert response.status_code == 304, header
    for header in ('"other"', 'W/"other"', tag[1:-1]):
        response = client.get(url, headers={**AUTH_A, "If-None-Match": header})
        assert response.status_code == 200 and response.content == BLOB, header


def test_if_range_keeps_strong_comparison(client, url):
    """If-None-Match ignores `W/` (the weak match must not leak into If-Range, RFC 9110 13.1.5)."""
    tag = f'"{hashlib.sha256(BLOB).hexdigest()}"'
    weak = client.get(url, headers={**AUTH_A, "Range": "bytes=0-9", "If-Range": f"W/{tag}"})
    assert weak.status_code == 200 and weak.content == BLOB
    strong = client.get(url, headers={**AUTH_A, "Range": "bytes=0-9", "If-Range": tag})
    assert strong.status_code == 206 and strong.content == BLOB[:10]


def test_head_on_an_artifact_sends_the_get_headers_without_a_body(client, url):
    """No HEAD on artifacts."""
    got = client.get(url, headers=AUTH_A)
    head = client.head(url, headers=AUTH_A)
    assert head.status_code == 200 and head.content == b""
    for name in ("content-length", "etag", "accept-ranges", "content-type"):
        assert head.headers[name] == got.headers[name], name
    assert head.headers["content-length"] == str(len(BLOB))
    ranged = client.head(url, headers={**AUTH_A, "Range": "bytes=0-9"})
    assert ranged.status_code == 200 and ranged.headers["content-length"] == str(len(BLOB))
    cached = client.head(url, headers={**AUTH_A, "If-None-Match": got.headers["etag"]})
    assert cached.status_code == 304
    missing = client.head(url.replace("scene.ply", "nope.ply"), headers=AUTH_A)
    assert missing.status_code == 404
    assert client.head(url).status_code == 401
