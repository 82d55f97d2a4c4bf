"""``/v1/jobs``: create (202, idempotent), read (ETag), list (paged), cancel, delete, and the
job's webhook deliveries."""

from __future__ import annotations

import logging
from typing import Annotated, Any, cast

from fastapi import APIRouter, Header, Query, Response
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse
from sqlalchemy.exc import IntegrityError

from dcseg.errors import InputError
from dcseg.options import build_config, check_size
from jobstore.contract import TERMINAL
from jobstore.models import Job, WebhookAttempt, WebhookDelivery
from jobstore.store import Conflict, Cursor, TooManyJobs, new_id
from service.deps import AppState, StateDep, TenantDep
from service.exports import remove_cached
from service.idempotency import IdempotencyKeyHeader, idempotent
from service.jobs import (
    decode_page_token,
    encode_page_token,
    etag_matches,
    etag_of,
    job_public,
    job_url,
    request_hash,
)
from service.problems import ApiProblem, problem_responses
from service.schemas import (
    DeliveryState,
    JobCreate,
    JobPublic,
    JobsPublic,
    JobStatus,
    TerminalStatus,
    WebhookAttemptPublic,
    WebhookDeliveriesPublic,
    WebhookDeliveryPublic,
)
from service.webhooks import url_refusal

logger = logging.getLogger(__name__)

router = APIRouter(prefix="/v1/jobs", tags=["jobs"])


def _not_found(job_id: str) -> ApiProblem:
    return ApiProblem(404, f"no job {job_id!r}", slug="not-found", job_id=job_id)


def _job_response(state: AppState, job: Job, status_code: int = 200) -> JSONResponse:
    body = job_public(job).model_dump(mode="json")
    headers = {"ETag": etag_of(body)}
    if job.status not in TERMINAL:
        headers["Retry-After"] = str(state.settings.retry_after_s)
    return JSONResponse(body, status_code=status_code, headers=headers)


def _new_job(state: AppState, tenant: str, body: JobCreate) -> Job:
    """Check the inputs, then insert the queued job within the tenant's cap."""
    upload_id = body.upload_id
    if body.parent_job_id is not None:
        parent = state.store.get_job(body.parent_job_id, tenant)
        if parent is None:
            raise _not_found(body.parent_job_id)
        if parent.status != "succeeded":
            raise ApiProblem(
                409, f"parent job is {parent.status}, not succeeded", slug="parent-unfinished"
            )
        upload_id = upload_id or parent.upload_id
    assert upload_id is not None
    upload = state.store.get_upload(upload_id, tenant)
    if upload is None:
        raise ApiProblem(404, f"no upload {upload_id!r}", slug="not-found")
    check_options(body, upload.summary)
    if body.callback_url is not None:
        check_callback_url(state, body.callback_url)
    config = {"preset": body.preset, "options": body.options.stored()}
    job = Job(
        id=new_id(),
        tenant_id=tenant,
        upload_id=upload_id,
        parent_job_id=body.parent_job_id,
        status="queued",
        config=config,
        event_seq=0,
        message="queued",
        callback_url=body.callback_url,
    )
    return _insert_capped(state, job)


def _insert_capped(state: AppState, job: Job) -> Job:
    """Insert the job unless its tenant is at its cap (checked in the insert's transaction)."""
    try:
        return state.store.create_job(job, max_active=state.settings.max_running_jobs_per_tenant)
    except TooManyJobs as full:
        raise ApiProblem(
            429, str(full), slug="too-many-jobs", headers={"Retry-After": "30"}
        ) from None
    except IntegrityError:
        if state.store.get_upload(job.upload_id, job.tenant_id) is not None:
            raise
        # deleted (or expired) since the check in _new_job: the job's foreign key refused it
        raise ApiProblem(
            404, f"no upload {job.upload_id!r} (it was deleted)", slug="not-found"
        ) from None


def check_options(body: JobCreate, summary: dict[str, Any]) -> None:
    """422 naming the field when the options are refused by the config builder the worker
    uses (cross-field rules) or would upscale the upload's frames."""
    try:
        build_config(body.preset, body.options)
        check_size(body.options, native_size(summary), "options.capture.size")
    except InputError as error:
        items = [{"path": f"body.{p.path}", "reason": p.reason} for p in error.problems]
        detail = f"{len(items)} invalid field(s): " + "; ".join(
            f"{i['path']}: {i['reason']}" for i in items
        )
        raise ApiProblem(
            422, detail, slug="validation-error", title="Request validation failed", errors=items
        ) from None


def _invalid(path: str, reason: str) -> ApiProblem:
    """422 naming one body field, in the shape of request validation errors."""
    return ApiProblem(
        422,
        f"1 invalid field(s): body.{path}: {reason}",
        slug="validation-error",
        title="Request validation failed",
        errors=[{"path": f"body.{path}", "reason": reason}],
    )


def check_callback_url(state: AppState, url: str) -> None:
    """422 naming ``callback_url`` when webhooks are off or its host is not allowed."""
    settings = state.settings
    if not settings.webhook_secret.get_secret_value():
        raise _invalid("callback_url", "webhooks are off on this server (no DCSEG_WEBHOOK_SECRET)")
    refusal = url_refusal(url, settings.webhook_allow_private)
    if refusal is not None:
        raise _invalid("callback_url", refusal)


def native_size(summary: dict[str, Any]) -> tuple[int, int] | None:
    """The smallest frame size an upload's validation summary reports (``"WxH"`` strings)."""
    sizes = [
        tuple(int(v) for v in str(s).split("x"))
        for s in summary.get("capture", {}).get("resolution", [])
    ]
    if not sizes:
        return None
    return min(w for w, _ in sizes), min(h for _, h in sizes)


def _callback_part(body: JobCreate) -> dict[str, str]:
    """``callback_url`` as part of the request hash, when given."""
    return {} if body.callback_url is None else {"callback_url": body.callback_url}


def _submit(state: AppState, tenant: str, body: JobCreate) -> JSONResponse:
    job = _new_job(state, tenant, body)
    try:
        state.queue.enqueue(job.id)
    except Exception as error:
        error_id = new_id()
        logger.exception("could not enqueue job %s (error id %s)", job.id, error_id)
        detail = f"the job queue was unavailable (error id {error_id}); submit the job again"
        body_ = {"type": "queue-unavailable", "detail": detail, "error_id": error_id}
        state.store.finish_job(job.id, "failed", body_)
        raise ApiProblem(
            503, "the job queue is unavailable; try again later", slug="queue-down"
        ) from error
    response = _job_response(state, job, 202)
    response.headers["Location"] = job_url(job.id)
    response.headers["Operation-Location"] = job_url(job.id)
    return response


@router.post(
    "",
    status_code=202,
    response_model=JobPublic,
    responses=problem_responses(400, 401, 404, 409, 422, 429, 503),
    operation_id="createJob",
)
def create_job(
    body: JobCreate,
    state: StateDep,
    tenant: TenantDep,
    idempotency_key: IdempotencyKeyHeader = None,
) -> Response:
    """Queue a pipeline run; poll the job at ``Location`` (or stream its events)."""
    # without a callback_url the hash is the one keys got before the field existed
    digest = request_hash(
        body.model_dump(mode="json", exclude={"callback_url"}) | _callback_part(body)
    )
    with idempotent(state, tenant, idempotency_key, digest) as request:
        if request.replay is not None:
            return request.replay
        return request.keep(_submit(state, tenant, body))


@router.get(
    "",
    response_model=JobsPublic,
    responses=problem_responses(400, 401, 422),
    operation_id="listJobs",
)
def list_jobs(
    state: StateDep,
    tenant: TenantDep,
    page_size: Annotated[int, Query(ge=1, le=100)] = 20,
    page_token: Annotated[str | None, Query(max_length=500)] = None,
    status: JobStatus | None = None,
) -> JobsPublic:
    """The tenant's jobs, newest first; follow ``next_page_token`` until it is absent."""
    after = decode_page_token(page_token, status) if page_token else None
    jobs, more = state.store.list_jobs(tenant, status=status, after=after, limit=page_size)
    token = None
    if more and jobs:
        token = encode_page_token(Cursor(jobs[-1].created_at, jobs[-1].id), status)
    return JobsPublic(jobs=[job_public(j) for j in jobs], next_page_token=token)


@router.get(
    "/{job_id}",
    response_model=JobPublic,
    responses={304: {"description": "Not Modified"}, **problem_responses(401, 404)},
    operation_id="getJob",
)
def get_job(
    job_id: str,
    state: StateDep,
    tenant: TenantDep,
    if_none_match: Annotated[str | None, Header()] = None,
) -> Response:
    """A job's status, stage, progress, timings, error and links; ``Retry-After`` until done."""
    job = state.store.get_job(job_id, tenant)
    if job is None:
        raise _not_found(job_id)
    response = _job_response(state, job)
    if etag_matches(if_none_match, response.headers["etag"]):
        return Response(status_code=304, headers={"ETag": response.headers["etag"]})
    return response


def _cancel(job_id: str, state: AppState, tenant: str) -> Response:
    try:
        job = state.store.request_cancel(job_id, tenant)
    except Conflict as conflict:
        raise ApiProblem(409, conflict.detail, slug="job-finished", job_id=job_id) from None
    if job is None:
        raise _not_found(job_id)
    return _job_response(state, job)


@router.post(
    "/{job_id}:cancel",
    response_model=JobPublic,
    responses=problem_responses(401, 404, 409),
    operation_id="cancelJob",
)
def cancel_job(job_id: str, state: StateDep, tenant: TenantDep) -> Response:
    """Cancel: a queued job ends ``canceled`` at once, a running one passes through
    ``canceling`` until its worker stops between iterations. 409 when already finished."""
    return _cancel(job_id, state, tenant)


@router.post(
    "/{job_id}/cancel",
    response_model=JobPublic,
    responses=problem_responses(401, 404, 409),
    include_in_schema=False,
    operation_id="cancelJobAlias",
)
def cancel_job_alias(job_id: str, state: StateDep, tenant: TenantDep) -> Response:
    return _cancel(job_id, state, tenant)


@router.delete(
    "/{job_id}",
    status_code=204,
    responses=problem_responses(401, 404, 409),
    operation_id="deleteJob",
)
async def delete_job(job_id: str, state: StateDep, tenant: TenantDep) -> Response:
    """Delete a finished job and its artifacts. An unfinished job answers 409: cancel it first
    and delete it once it is ``canceled``."""
    try:
        job = await run_in_threadpool(state.store.delete_job, job_id, tenant)
    except Conflict as conflict:
        raise ApiProblem(409, conflict.detail, slug="job-unfinished", job_id=job_id) from None
    if job is None:
        raise _not_found(job_id)
    await run_in_threadpool(state.storage.remove_job, tenant, job_id)
    await run_in_threadpool(remove_cached, state.settings, job_id)
    return Response(status_code=204)


def _delivery_public(
    delivery: WebhookDelivery, attempts: list[WebhookAttempt]
) -> WebhookDeliveryPublic:
    return WebhookDeliveryPublic(
        id=delivery.id,
        url=delivery.url,
        job_status=cast(TerminalStatus, delivery.job_status),
        state=cast(DeliveryState, delivery.state),
        next_attempt_at=delivery.next_attempt_at if delivery.state == "pending" else None,
        created_at=delivery.created_at,
        completed_at=delivery.completed_at,
        attempts=[
            WebhookAttemptPublic(
                attempt=a.attempt,
                attempted_at=a.attempted_at,
                status_code=a.status_code,
                error=a.error,
            )
            for a in attempts
        ],
    )


@router.get(
    "/{job_id}/webhook-deliveries",
    response_model=WebhookDeliveriesPublic,
    responses=problem_responses(401, 404),
    operation_id="listWebhookDeliveries",
)
def list_webhook_deliveries(
    job_id: str, state: StateDep, tenant: TenantDep
) -> WebhookDeliveriesPublic:
    """The job's webhook deliveries (made when a job with a ``callback_url`` ends) and every
    attempt of each: time, attempt number, the receiver's status code or the error."""
    if state.store.get_job(job_id, tenant) is None:
        raise _not_found(job_id)
    rows = state.store.webhook_deliveries(job_id)
    return WebhookDeliveriesPublic(deliveries=[_delivery_public(d, a) for d, a in rows])
