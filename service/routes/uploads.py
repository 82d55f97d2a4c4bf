"""``POST /v1/uploads`` (a capture archive, streamed) and ``GET /v1/uploads/{id}``."""

from __future__ import annotations

import os
from typing import Annotated

from fastapi import APIRouter, Header, Query, Request, Response
from fastapi.concurrency import run_in_threadpool

from service import uploads
from service.deps import StateDep, TenantDep
from service.models import Upload
from service.problems import ApiProblem, problem_responses
from service.schemas import UploadLinks, UploadPublic
from service.store import UploadInUse, new_id
from worker.contract import UploadPaths

router = APIRouter(prefix="/v1/uploads", tags=["uploads"])

_BODY = {
    "requestBody": {
        "required": True,
        "description": "A .zip, .tar or .tar.gz whose root holds the capture (any layout "
        "dcseg reads) and optionally masks/agnostic/, masks/semantic/, vocabulary.txt|json "
        "and gt/points.ply.",
        "content": {
            t: {"schema": {"type": "string", "format": "binary"}}
            for t in sorted(uploads.ACCEPTED_TYPES)
        },
    }
}


def upload_public(upload: Upload) -> UploadPublic:
    return UploadPublic(
        id=upload.id,
        sha256=upload.sha256,
        size=upload.size,
        content_type=upload.content_type,
        summary=upload.summary,
        created_at=upload.created_at,
        links=UploadLinks(self=f"/v1/uploads/{upload.id}"),
    )


@router.post(
    "",
    status_code=201,
    response_model=UploadPublic,
    openapi_extra=_BODY,
    responses=problem_responses(400, 401, 413, 415, 422, 429),
)
async def create_upload(
    request: Request,
    response: Response,
    state: StateDep,
    tenant: TenantDep,
    sha256: Annotated[str | None, Query(description="expected SHA-256 (hex) of the body")] = None,
    repr_digest: Annotated[str | None, Header(description="RFC 9530: sha-256=:<b64>:")] = None,
    content_length: Annotated[int | None, Header()] = None,
) -> UploadPublic:
    """Upload a capture archive; it is validated before it is accepted (422 lists problems)."""
    content_type = uploads.media_type(request.headers.get("content-type"))
    if content_type not in uploads.ACCEPTED_TYPES:
        raise ApiProblem(
            415,
            f"content type {content_type or '(none)'!r} is not an accepted archive type "
            f"({', '.join(sorted(uploads.ACCEPTED_TYPES))})",
            slug="unsupported-media-type",
        )
    expected = uploads.expected_digest(repr_digest, sha256)
    limit = state.settings.max_upload_bytes
    if content_length is not None and content_length > limit:
        raise uploads.too_large(limit)
    upload_id = new_id()
    paths = UploadPaths(state.settings.storage_dir, upload_id)
    tmp = paths.folder.with_name(f".tmp-{upload_id}")
    tmp.mkdir(parents=True)
    try:
        archive = tmp / "archive"
        size, digest = await uploads.receive(request.stream(), archive, limit)
        if expected is not None and expected != digest:
            raise ApiProblem(
                422,
                f"body SHA-256 {digest} does not match the announced {expected}",
                slug="digest-mismatch",
            )
        summary = await run_in_threadpool(
            uploads.extract_and_validate, archive, tmp / "data", state.settings
        )
        archive.unlink()
        os.rename(tmp, paths.folder)
    except BaseException:
        uploads.remove(tmp)
        raise
    record = Upload(
        id=upload_id,
        tenant_id=tenant,
        sha256=digest,
        size=size,
        content_type=content_type,
        summary=summary,
    )
    try:
        state.store.add_upload(record)
    except BaseException:
        uploads.remove(paths.folder)
        raise
    response.headers["Location"] = f"/v1/uploads/{upload_id}"
    return upload_public(record)


@router.get("/{upload_id}", response_model=UploadPublic, responses=problem_responses(401, 404))
def get_upload(upload_id: str, state: StateDep, tenant: TenantDep) -> UploadPublic:
    """An upload's digest, size and validation summary."""
    upload = state.store.get_upload(upload_id, tenant)
    if upload is None:
        raise ApiProblem(404, f"no upload {upload_id!r}", slug="not-found")
    return upload_public(upload)


@router.delete("/{upload_id}", status_code=204, responses=problem_responses(401, 404, 409))
async def delete_upload(upload_id: str, state: StateDep, tenant: TenantDep) -> Response:
    """Delete an upload and its files; 409 while jobs refer to it (delete those first)."""
    try:
        upload = await run_in_threadpool(state.store.delete_upload, upload_id, tenant)
    except UploadInUse as in_use:
        raise ApiProblem(409, str(in_use), slug="upload-in-use") from None
    if upload is None:
        raise ApiProblem(404, f"no upload {upload_id!r}", slug="not-found")
    folder = UploadPaths(state.settings.storage_dir, upload_id).folder
    await run_in_threadpool(uploads.remove, folder)
    return Response(status_code=204)
