"""``GET /v1/jobs/{id}/instances`` (paged, filtered by class) and ``/instances/{k}``."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Path, Query

from service import instances
from service.deps import StateDep, TenantDep
from service.exports import FORMATS
from service.problems import problem_responses
from service.schemas import InstanceLinks, InstancePublic, InstancesPublic

router = APIRouter(prefix="/v1/jobs", tags=["instances"])

InstanceId = Annotated[int, Path(ge=1, le=2**31 - 1, description="instance id (from 1)")]


def _files(job_id: str, state: StateDep, tenant: str) -> instances.JobFiles:
    job = state.store.get_job(job_id, tenant)
    return instances.finished_job(state.storage, tenant, job, job_id)


def instance_url(job_id: str, k: int) -> str:
    return f"/v1/jobs/{job_id}/instances/{k}"


def instance_public(job_id: str, record: dict[str, Any]) -> InstancePublic:
    k = int(record["id"])
    url = instance_url(job_id, k)
    links = InstanceLinks(self=url, exports={f: f"{url}/exports/{f}" for f in FORMATS})
    return InstancePublic(**{**record, "size": instances.extent(record), "links": links})


@router.get(
    "/{job_id}/instances",
    response_model=InstancesPublic,
    responses=problem_responses(400, 401, 404, 409, 422),
    operation_id="listInstances",
)
def list_instances(
    job_id: str,
    state: StateDep,
    tenant: TenantDep,
    page_size: Annotated[int, Query(ge=1, le=500)] = 100,
    page_token: Annotated[str | None, Query(max_length=500)] = None,
    label: Annotated[
        list[str] | None,
        Query(max_length=200, description="class name; repeat for several classes"),
    ] = None,
    min_score: Annotated[float | None, Query(ge=0.0, le=1.0, allow_inf_nan=False)] = None,
) -> InstancesPublic:
    """The objects of a succeeded job, by id; follow ``next_page_token`` until it is absent.
    409 while the job has not succeeded, 404 when it segmented nothing (no masks uploaded)."""
    files = _files(job_id, state, tenant)
    body = instances.read_instances(files)
    records: list[dict[str, Any]] = body.get("instances", [])
    keep = instances.Filter(labels=tuple(label or ()), min_score=min_score)
    instances.check_labels(keep.labels, instances.vocabulary(files, records))
    after = instances.decode_token(page_token, keep) if page_token else None
    chosen, more = instances.page(records, keep, after, page_size)
    token = instances.encode_token(int(chosen[-1]["id"]), keep) if more and chosen else None
    return InstancesPublic(
        instances=[instance_public(job_id, r) for r in chosen],
        next_page_token=token,
        scene_sha256=body.get("scene_sha256"),
    )


@router.get(
    "/{job_id}/instances/{k}",
    response_model=InstancePublic,
    responses=problem_responses(401, 404, 409, 422),
    operation_id="getInstance",
)
def get_instance(job_id: str, k: InstanceId, state: StateDep, tenant: TenantDep) -> InstancePublic:
    """One object: its class, score, size, box, visibility and download links per format."""
    files = _files(job_id, state, tenant)
    records = instances.read_instances(files).get("instances", [])
    return instance_public(job_id, instances.find_instance(records, job_id, k))
