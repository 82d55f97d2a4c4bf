"""``POST /v1/direct-uploads`` and ``/v1/direct-uploads/{id}:complete``: large archives sent
straight to object storage by presigned multipart upload, validated by the API afterwards.

The first call answers one presigned ``PUT`` URL per part; the client sends the parts to the
store and completes with their ETags. The API then joins the parts, fetches the archive, checks
its size and SHA-256 and validates it exactly like ``POST /v1/uploads`` (same pool, limits,
quota and 422 problems); only a valid archive becomes an upload. Object storage only: with
local storage both answer 409 ``direct-uploads-unavailable`` (the server's configuration, not
the request, is what conflicts; a 5xx would tell clients to retry).
"""

from __future__ import annotations

import math
from datetime import timedelta
from functools import partial
from typing import Any

from fastapi import APIRouter, Request, Response
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse

from jobstore.contract import UploadPaths
from jobstore.models import Upload, utcnow
from jobstore.s3 import S3Storage, is_missing
from jobstore.store import new_id
from service import uploads
from service.deps import AppState, StateDep, TenantDep
from service.problems import ApiProblem, problem_responses
from service.routes.uploads import _created, _store
from service.schemas import (
    DirectUploadComplete,
    DirectUploadCreate,
    DirectUploadLinks,
    DirectUploadPart,
    DirectUploadPublic,
    UploadPublic,
)

router = APIRouter(prefix="/v1/direct-uploads", tags=["uploads"])

MAX_PARTS = 10_000
"""S3's largest part count."""


def _s3(state: AppState) -> S3Storage:
    if not isinstance(state.storage, S3Storage):
        raise ApiProblem(
            409,
            "direct uploads need object storage (DCSEG_STORAGE_BACKEND=s3); this server stores"
            " files locally: send the archive to POST /v1/uploads",
            slug="direct-uploads-unavailable",
        )
    return state.storage


def _meta_key(storage: S3Storage, tenant: str, upload_id: str) -> str:
    return storage.key(tenant, f"direct-uploads/{upload_id}.json")


@router.post(
    "",
    status_code=201,
    response_model=DirectUploadPublic,
    responses=problem_responses(401, 409, 413, 422, 429, 507),
    operation_id="createDirectUpload",
)
def create_direct_upload(
    body: DirectUploadCreate, state: StateDep, tenant: TenantDep
) -> JSONResponse:
    """Start a direct upload of an archive of ``size`` bytes: presigned part URLs, valid for
    ``DCSEG_PRESIGN_EXPIRY_S``. 413 past ``DCSEG_MAX_UPLOAD_BYTES``, 507 past the quota."""
    storage = _s3(state)
    limit = state.settings.max_upload_bytes
    if body.size > limit:
        raise uploads.too_large(limit)
    uploads.check_room(state, tenant, body.size)
    part_size = max(state.settings.direct_upload_part_bytes, math.ceil(body.size / MAX_PARTS))
    count = math.ceil(body.size / part_size)
    upload_id = new_id()
    multipart_id, urls = storage.start_multipart(tenant, upload_id, count)
    meta = {**body.model_dump(), "multipart_id": multipart_id, "part_size": part_size}
    storage.put_json(_meta_key(storage, tenant, upload_id), meta)
    complete = f"/v1/direct-uploads/{upload_id}:complete"
    public = DirectUploadPublic(
        id=upload_id,
        content_type=body.content_type,
        size=body.size,
        part_size=part_size,
        parts=[DirectUploadPart(part_number=i + 1, url=url) for i, url in enumerate(urls)],
        expires_at=utcnow() + timedelta(seconds=state.settings.presign_expiry_s),
        links=DirectUploadLinks(complete=complete),
    )
    return JSONResponse(public.model_dump(mode="json"), status_code=201)


def _join(storage: S3Storage, tenant: str, upload_id: str, meta: dict[str, Any], body: Any) -> None:
    """Complete the multipart upload; 409 when it is gone, 422 when S3 refuses the parts."""
    from botocore.exceptions import ClientError

    parts = sorted((p.part_number, p.etag) for p in body.parts)
    try:
        storage.complete_multipart(tenant, upload_id, str(meta["multipart_id"]), parts)
    except ClientError as error:
        code = error.response.get("Error", {}).get("Code", "error")
        if is_missing(error):
            raise ApiProblem(
                409,
                f"direct upload {upload_id} was completed or aborted already",
                slug="direct-upload-gone",
            ) from None
        raise ApiProblem(
            422,
            f"the store refused the parts ({code}): every part must be uploaded, listed once"
            " with the ETag its PUT answered, and all but the last be part_size bytes",
            slug="invalid-parts",
            errors=[{"path": "body.parts", "reason": str(code)}],
        ) from None


def _fetch(storage: S3Storage, tenant: str, upload_id: str, meta: dict[str, Any], tmp: Any) -> str:
    """Fetch the joined archive into ``tmp/archive``; its SHA-256; 422 on a size or digest
    mismatch."""
    key = storage.direct_key(tenant, upload_id)
    try:
        size, digest = storage.download(key, tmp / "archive", int(meta["size"]))
    except ValueError:
        size, digest = int(meta["size"]) + 1, ""
    if size != int(meta["size"]):
        raise ApiProblem(
            422,
            f"the uploaded parts hold {size} bytes, not the announced size {meta['size']}",
            slug="size-mismatch",
        )
    if meta.get("sha256") and meta["sha256"] != digest:
        raise ApiProblem(
            422,
            f"body SHA-256 {digest} does not match the announced {meta['sha256']}",
            slug="digest-mismatch",
        )
    return digest


def _discard(storage: S3Storage, tenant: str, upload_id: str) -> None:
    storage.delete_prefix(storage.key(tenant, f"direct-uploads/{upload_id}"))


@router.post(
    "/{upload_id}:complete",
    status_code=201,
    response_model=UploadPublic,
    responses=problem_responses(401, 404, 409, 413, 422, 429, 503, 507),
    operation_id="completeDirectUpload",
)
async def complete_direct_upload(
    upload_id: str,
    body: DirectUploadComplete,
    request: Request,
    state: StateDep,
    tenant: TenantDep,
) -> Response:
    """Join the parts, then check and validate the archive like ``POST /v1/uploads`` (422
    lists every problem); 201 with the upload. An invalid archive is deleted from the store;
    refused parts (422 ``invalid-parts``) can be fixed and completed again."""
    storage = _s3(state)
    meta = await run_in_threadpool(storage.get_json, _meta_key(storage, tenant, upload_id))
    if not isinstance(meta, dict):
        raise ApiProblem(404, f"no direct upload {upload_id!r}", slug="not-found")
    with uploads.validation_pool(request.app.state, state.settings).admit():
        await run_in_threadpool(partial(uploads.check_room, state, tenant, int(meta["size"])))
        await run_in_threadpool(_join, storage, tenant, upload_id, meta, body)
        tmp = UploadPaths(state.settings.storage_dir, upload_id).folder.with_name(
            f".tmp-{upload_id}"
        )
        try:
            with uploads.disk_full_as_507():
                tmp.mkdir(parents=True)
                digest = await run_in_threadpool(_fetch, storage, tenant, upload_id, meta, tmp)
                record = Upload(
                    id=upload_id,
                    tenant_id=tenant,
                    sha256=digest,
                    size=int(meta["size"]),
                    content_type=str(meta["content_type"]),
                    summary={},
                )
                record = await _store(request, state, tmp, record)
        finally:
            uploads.remove(tmp)
            await run_in_threadpool(_discard, storage, tenant, upload_id)
    return _created(record)
