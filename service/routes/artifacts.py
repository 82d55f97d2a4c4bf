"""``GET /v1/jobs/{id}/artifacts`` and ``/artifacts/{name}`` (ETag, Range)."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Header, Response
from fastapi.responses import StreamingResponse

from service import artifacts
from service.deps import StateDep, TenantDep
from service.problems import ApiProblem, problem_responses
from service.schemas import ArtifactPublic, ArtifactsPublic
from worker.contract import JobPaths

router = APIRouter(prefix="/v1/jobs", tags=["artifacts"])


def _output(job_id: str, state: StateDep, tenant: str) -> JobPaths:
    if state.store.get_job(job_id, tenant) is None:
        raise ApiProblem(404, f"no job {job_id!r}", slug="not-found", job_id=job_id)
    return JobPaths(state.settings.storage_dir, job_id)


@router.get(
    "/{job_id}/artifacts", response_model=ArtifactsPublic, responses=problem_responses(401, 404)
)
def list_artifacts(job_id: str, state: StateDep, tenant: TenantDep) -> ArtifactsPublic:
    """The files of the job's finished stages (immutable once listed)."""
    paths = _output(job_id, state, tenant)
    items = [
        ArtifactPublic(
            name=a.name,
            media_type=a.media_type,
            size=a.size,
            sha256=a.sha256,
            url=f"/v1/jobs/{job_id}/artifacts/{a.name}",
        )
        for a in artifacts.list_artifacts(paths.output)
    ]
    return ArtifactsPublic(artifacts=items)


@router.get(
    "/{job_id}/artifacts/{name:path}",
    response_class=StreamingResponse,
    responses={
        200: {"content": {"application/octet-stream": {}}, "description": "the file"},
        206: {"description": "Partial Content"},
        304: {"description": "Not Modified"},
        **problem_responses(401, 404, 416),
    },
)
def download_artifact(
    job_id: str,
    name: str,
    state: StateDep,
    tenant: TenantDep,
    range_header: Annotated[str | None, Header(alias="Range")] = None,
    if_range: Annotated[str | None, Header()] = None,
    if_none_match: Annotated[str | None, Header()] = None,
) -> Response:
    """Download one artifact; honours ``Range: bytes=a-b``, ``If-Range`` and ``If-None-Match``."""
    paths = _output(job_id, state, tenant)
    found = artifacts.find_artifact(paths.output, name)
    if found is None:
        raise ApiProblem(404, f"job {job_id} has no artifact {name!r}", slug="not-found")
    headers = {"ETag": found.etag, "Accept-Ranges": "bytes", "Cache-Control": "private"}
    if if_none_match and found.etag in [t.strip() for t in if_none_match.split(",")]:
        return Response(status_code=304, headers=headers)
    use_range = if_range is None or if_range.strip() == found.etag
    span = artifacts.parse_range(range_header, found.size) if use_range else None
    if span is None:
        body = artifacts.read_bytes(found.path, 0, found.size - 1)
        headers["Content-Length"] = str(found.size)
        return StreamingResponse(body, media_type=found.media_type, headers=headers)
    start, end = span
    headers["Content-Range"] = f"bytes {start}-{end}/{found.size}"
    headers["Content-Length"] = str(end - start + 1)
    body = artifacts.read_bytes(found.path, start, end)
    return StreamingResponse(body, status_code=206, media_type=found.media_type, headers=headers)
