"""``POST /v1/uploads`` (a capture archive, streamed, idempotent), ``GET`` and ``DELETE``."""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Annotated

from fastapi import APIRouter, Header, Query, Request, Response
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse

from jobstore.contract import UploadPaths
from jobstore.models import Upload
from jobstore.store import UploadInUse, new_id
from service import uploads
from service.deps import AppState, StateDep, TenantDep
from service.idempotency import IdempotencyKeyHeader, idempotent_async
from service.problems import ApiProblem, problem_responses
from service.schemas import UploadLinks, UploadPublic

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


def _media_type(request: Request) -> str:
    content_type = uploads.media_type(request.headers.get("content-type"))
    if content_type not in uploads.ACCEPTED_TYPES:
        raise ApiProblem(
            415,
            f"content type {content_type or '(none)'!r} is not an accepted archive type "
            f"({', '.join(sorted(uploads.ACCEPTED_TYPES))})",
            slug="unsupported-media-type",
        )
    return content_type


def _created(record: Upload) -> JSONResponse:
    body = upload_public(record).model_dump(mode="json")
    return JSONResponse(body, status_code=201, headers={"Location": body["links"]["self"]})


@dataclass(frozen=True)
class _Incoming:
    """An upload being received into its temporary folder."""

    upload_id: str
    tmp: Path
    content_type: str
    expected: str | None
    """The SHA-256 the client announced, if any."""


async def _receive(request: Request, state: AppState, incoming: _Incoming) -> tuple[int, str]:
    """Stream the body into ``tmp/archive``; 413 past the cap, 422 on a digest mismatch."""
    size, digest = await uploads.receive(
        request.stream(), incoming.tmp / "archive", state.settings.max_upload_bytes
    )
    if incoming.expected is not None and incoming.expected != digest:
        raise ApiProblem(
            422,
            f"body SHA-256 {digest} does not match the announced {incoming.expected}",
            slug="digest-mismatch",
        )
    return size, digest


async def _store(request: Request, state: AppState, tmp: Path, record: Upload) -> Upload:
    """Extract and validate in the pool, check room for it, then move it into place."""
    pool = uploads.validation_pool(request.app.state, state.settings)
    summary, stored = await pool.run(uploads.prepare, tmp / "archive", tmp / "data", state.settings)
    check = partial(uploads.check_room, state, record.tenant_id)
    await run_in_threadpool(partial(check, stored, written=True))
    await run_in_threadpool(state.storage.keep_upload, record.tenant_id, record.id, tmp)
    record.summary, record.stored_bytes = summary, stored
    try:
        await run_in_threadpool(state.store.add_upload, record)
    except BaseException:
        await run_in_threadpool(state.storage.remove_upload, record.tenant_id, record.id)
        raise
    return record


async def _accept(
    request: Request, state: AppState, tenant: str, incoming: _Incoming, key: str | None
) -> Response:
    """Receive, then (unless ``key`` replays an earlier upload) validate and keep it."""
    size, digest = await _receive(request, state, incoming)
    request_hash = uploads.upload_request_hash(incoming.content_type, digest)
    async with idempotent_async(state, tenant, key, request_hash) as idem:
        if idem.replay is not None:
            return idem.replay
        record = Upload(
            id=incoming.upload_id,
            tenant_id=tenant,
            sha256=digest,
            size=size,
            content_type=incoming.content_type,
            summary={},
        )
        record = await _store(request, state, incoming.tmp, record)
        return idem.keep(_created(record))


@router.post(
    "",
    status_code=201,
    response_model=UploadPublic,
    openapi_extra=_BODY,
    responses=problem_responses(400, 401, 409, 413, 415, 422, 429, 503, 507),
    operation_id="createUpload",
)
async def create_upload(
    request: Request,
    state: StateDep,
    tenant: TenantDep,
    sha256: Annotated[str | None, Query(description="expected SHA-256 (hex) of the body")] = None,
    repr_digest: Annotated[str | None, Header(description="RFC 9530: sha-256=:<b64>:")] = None,
    content_length: Annotated[int | None, Header()] = None,
    idempotency_key: IdempotencyKeyHeader = None,
) -> Response:
    """Upload a capture archive; it is validated before it is accepted (422 lists problems).
    507 when the storage is full or the tenant's quota would be exceeded; 503 with
    ``Retry-After`` while the server is busy with as many uploads as it takes at once."""
    content_type = _media_type(request)
    expected = uploads.expected_digest(repr_digest, sha256)
    if content_length is not None and content_length > state.settings.max_upload_bytes:
        raise uploads.too_large(state.settings.max_upload_bytes)
    with uploads.validation_pool(request.app.state, state.settings).admit():
        check = partial(uploads.check_room, state, tenant)
        await run_in_threadpool(check, content_length or 0)
        upload_id = new_id()
        folder = UploadPaths(state.settings.storage_dir, upload_id).folder
        incoming = _Incoming(
            upload_id, folder.with_name(f".tmp-{upload_id}"), content_type, expected
        )
        try:
            with uploads.disk_full_as_507():
                incoming.tmp.mkdir(parents=True)
                return await _accept(request, state, tenant, incoming, idempotency_key)
        finally:
            uploads.remove(incoming.tmp)  # gone already when the upload was kept


@router.get(
    "/{upload_id}",
    response_model=UploadPublic,
    responses=problem_responses(401, 404),
    operation_id="getUpload",
)
def get_upload(upload_id: str, state: StateDep, tenant: TenantDep) -> UploadPublic:
    """An upload's digest, size and validation summary."""
    upload = state.store.get_upload(upload_id, tenant)
    if upload is None:
        raise ApiProblem(404, f"no upload {upload_id!r}", slug="not-found")
    return upload_public(upload)


@router.delete(
    "/{upload_id}",
    status_code=204,
    responses=problem_responses(401, 404, 409),
    operation_id="deleteUpload",
)
async def delete_upload(upload_id: str, state: StateDep, tenant: TenantDep) -> Response:
    """Delete an upload and its files; 409 while jobs refer to it (delete those first)."""
    try:
        upload = await run_in_threadpool(state.store.delete_upload, upload_id, tenant)
    except UploadInUse as in_use:
        raise ApiProblem(409, str(in_use), slug="upload-in-use") from None
    if upload is None:
        raise ApiProblem(404, f"no upload {upload_id!r}", slug="not-found")
    await run_in_threadpool(state.storage.remove_upload, tenant, upload_id)
    return Response(status_code=204)
