"""``GET /v1/jobs/{id}/artifacts`` and ``/artifacts/{name}`` (ETag, Range)."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from datetime import timedelta
from typing import Annotated

from fastapi import APIRouter, Header, Response
from fastapi.responses import StreamingResponse

from jobstore.models import utcnow
from service import artifacts
from service.deps import StateDep, TenantDep
from service.jobs import etag_matches
from service.problems import ApiProblem, problem_responses
from service.schemas import ArtifactPublic, ArtifactsPublic

router = APIRouter(prefix="/v1/jobs", tags=["artifacts"])


def _check_job(job_id: str, state: StateDep, tenant: str) -> None:
    if state.store.get_job(job_id, tenant) is None:
        raise ApiProblem(404, f"no job {job_id!r}", slug="not-found", job_id=job_id)


@router.get(
    "/{job_id}/artifacts",
    response_model=ArtifactsPublic,
    responses=problem_responses(401, 404),
    operation_id="listArtifacts",
)
def list_artifacts(job_id: str, state: StateDep, tenant: TenantDep) -> ArtifactsPublic:
    """The files of the job's finished stages (immutable once listed). With object storage
    each also has a presigned ``download_url`` valid for ``DCSEG_PRESIGN_EXPIRY_S``."""
    _check_job(job_id, state, tenant)
    expires = utcnow() + timedelta(seconds=state.settings.presign_expiry_s)
    items = []
    for a in artifacts.list_artifacts(state.storage, tenant, job_id):
        presigned = state.storage.presign(tenant, a.item)
        items.append(
            ArtifactPublic(
                name=a.name,
                media_type=a.media_type,
                size=a.size,
                sha256=a.sha256,
                url=f"/v1/jobs/{job_id}/artifacts/{a.name}",
                download_url=presigned,
                download_url_expires_at=expires if presigned else None,
            )
        )
    return ArtifactsPublic(artifacts=items)


DOWNLOAD = "/{job_id}/artifacts/{name:path}"
RangeHeader = Annotated[str | None, Header(alias="Range")]
IfRange = Annotated[str | None, Header()]
IfNoneMatch = Annotated[str | None, Header()]


def _find(job_id: str, name: str, state: StateDep, tenant: str) -> artifacts.Artifact:
    _check_job(job_id, state, tenant)
    found = artifacts.find_artifact(state.storage, tenant, job_id, name)
    if found is None:
        raise ApiProblem(404, f"job {job_id} has no artifact {name!r}", slug="not-found")
    return found


def _headers(found: artifacts.Artifact) -> dict[str, str]:
    return {"ETag": found.etag, "Accept-Ranges": "bytes", "Cache-Control": "private"}


@router.get(
    DOWNLOAD,
    response_class=StreamingResponse,
    responses={
        200: {"content": {"application/octet-stream": {}}, "description": "the file"},
        206: {"description": "Partial Content"},
        304: {"description": "Not Modified"},
        **problem_responses(401, 404, 416),
    },
    operation_id="downloadArtifact",
)
def download_artifact(
    job_id: str,
    name: str,
    state: StateDep,
    tenant: TenantDep,
    range_header: RangeHeader = None,
    if_range: IfRange = None,
    if_none_match: IfNoneMatch = None,
) -> Response:
    """Download one artifact; honours ``Range: bytes=a-b``, ``If-Range`` and ``If-None-Match``
    (``*`` and weak tags match)."""
    found = _find(job_id, name, state, tenant)

    def read(start: int, end: int) -> Iterator[bytes]:
        return state.storage.read(tenant, found.item, start, end)

    return send_file(found, read, range_header, if_range, if_none_match)


Reader = Callable[[int, int], Iterator[bytes]]
"""Bytes ``start..end`` (inclusive) of the file being sent, in chunks."""


def send_file(
    found: artifacts.Artifact,
    read: Reader,
    range_header: str | None,
    if_range: str | None,
    if_none_match: str | None,
) -> Response:
    """The download of ``found`` (artifact or export): ETag, Range, If-Range, If-None-Match."""
    headers = _headers(found)
    if etag_matches(if_none_match, found.etag):
        return Response(status_code=304, headers=headers)
    use_range = if_range is None or if_range.strip() == found.etag
    span = artifacts.parse_range(range_header, found.size) if use_range else None
    if span is None:
        body = read(0, found.size - 1)
        headers["Content-Length"] = str(found.size)
        return StreamingResponse(body, media_type=found.media_type, headers=headers)
    start, end = span
    headers["Content-Range"] = f"bytes {start}-{end}/{found.size}"
    headers["Content-Length"] = str(end - start + 1)
    body = read(start, end)
    return StreamingResponse(body, status_code=206, media_type=found.media_type, headers=headers)


@router.head(
    DOWNLOAD,
    response_class=Response,
    responses={
        200: {"description": "the headers of the download, no body"},
        304: {"description": "Not Modified"},
        **problem_responses(401, 404),
    },
    operation_id="headArtifact",
)
def artifact_headers(
    job_id: str,
    name: str,
    state: StateDep,
    tenant: TenantDep,
    if_none_match: IfNoneMatch = None,
) -> Response:
    """The headers a ``GET`` of the whole artifact sends (``Content-Length``, ``ETag``,
    ``Accept-Ranges``, ``Content-Type``), without a body; ``Range`` is ignored (RFC 9110 14.2)."""
    return send_headers(_find(job_id, name, state, tenant), if_none_match)


def send_headers(found: artifacts.Artifact, if_none_match: str | None) -> Response:
    """The headers of a whole download of ``found``, no body (``HEAD``)."""
    headers = _headers(found)
    if etag_matches(if_none_match, found.etag):
        return Response(status_code=304, headers=headers)
    headers["Content-Length"] = str(found.size)
    return Response(status_code=200, media_type=found.media_type, headers=headers)
