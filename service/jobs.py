"""Job resources: the public representation, ETags, page tokens and idempotency hashing."""

from __future__ import annotations

import base64
import hashlib
import json
from datetime import datetime
from typing import Any, cast

from jobstore.models import Job
from jobstore.store import Cursor
from service.problems import ApiProblem
from service.schemas import JobLinks, JobPublic, JobStatus, Progress


def job_url(job_id: str) -> str:
    return f"/v1/jobs/{job_id}"


def job_public(job: Job) -> JobPublic:
    url = job_url(job.id)
    return JobPublic(
        id=job.id,
        status=cast(JobStatus, job.status),  # the store writes only these
        stage=job.stage,
        progress=Progress(
            stage=job.stage,
            stage_index=job.stage_index,
            stage_count=job.stage_count,
            fraction=job.progress,
            message=job.message,
        ),
        error=job.error,
        config=job.config,
        upload_id=job.upload_id,
        parent_job_id=job.parent_job_id,
        created_at=job.created_at,
        started_at=job.started_at,
        updated_at=job.updated_at,
        completed_at=job.completed_at,
        links=JobLinks(
            self=url, cancel=f"{url}:cancel", events=f"{url}/events", artifacts=f"{url}/artifacts"
        ),
    )


def etag_of(body: dict[str, Any]) -> str:
    """A strong ETag of a JSON representation."""
    raw = json.dumps(body, sort_keys=True, separators=(",", ":")).encode()
    return '"' + hashlib.sha256(raw).hexdigest()[:32] + '"'


def etag_matches(if_none_match: str | None, etag: str) -> bool:
    if not if_none_match:
        return False
    tags = [t.strip().removeprefix("W/") for t in if_none_match.split(",")]
    return "*" in tags or etag in tags


def request_hash(body: dict[str, Any]) -> str:
    """Hash of a request body, to tell a replay from a different request under the same key."""
    raw = json.dumps(body, sort_keys=True, separators=(",", ":")).encode()
    return hashlib.sha256(raw).hexdigest()


def encode_page_token(cursor: Cursor, status: str | None) -> str:
    data = {"c": cursor.created_at.isoformat(), "i": cursor.job_id, "s": status}
    return base64.urlsafe_b64encode(json.dumps(data).encode()).decode().rstrip("=")


def decode_page_token(token: str, status: str | None) -> Cursor:
    """The cursor in ``token``; 400 when it is malformed or was made for another filter."""
    try:
        padded = token + "=" * (-len(token) % 4)
        data = json.loads(base64.urlsafe_b64decode(padded.encode()))
        cursor = Cursor(datetime.fromisoformat(data["c"]), str(data["i"]))
        token_status = data["s"]
    except (ValueError, KeyError, TypeError):
        raise ApiProblem(
            400, "page_token is not a token this API issued", slug="bad-page-token"
        ) from None
    if cursor.created_at.tzinfo is None or token_status != status:
        raise ApiProblem(
            400, "page_token was issued for another status filter", slug="bad-page-token"
        )
    return cursor
