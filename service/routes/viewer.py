"""``GET /viewer/{job_id}``: the browser viewer of a job's segmented scene, its static files
and ``/viewer/{job_id}/frame.json`` (the scene's up axis, :mod:`service.viewer_frame`).

The page and its script hold no job data and need no key: the page asks the user for the API
key (kept in the tab's sessionStorage) and fetches the job's artifacts with an
``Authorization`` header, so no key ever appears in a URL or an access log; ``frame.json`` is
fetched the same way (it is the job's data). Not part of the OpenAPI schema (HTML for people,
not an API).
"""

from __future__ import annotations

import uuid

from fastapi import APIRouter
from fastapi.responses import FileResponse, HTMLResponse, Response

from dcseg.viewer import (
    CONTENT_SECURITY_POLICY,
    STATIC_FILES,
    ViewerConfig,
    ViewerFiles,
    ViewerNotBuilt,
    bundle,
    render_page,
    static_file,
)
from dcseg.viewer.frame import FRAME_FILE
from service.deps import StateDep, TenantDep
from service.instances import finished_job
from service.problems import ApiProblem
from service.viewer_frame import job_frame

router = APIRouter(tags=["viewer"], include_in_schema=False)

SEGMENT_FILES = ("segment/scene_labelled.ply", "segment/instances.json", "segment/labels.json")
"""The artifacts the viewer reads (downloaded through ``/v1/jobs/{id}/artifacts/...``)."""

PAGE_HEADERS = {
    "Content-Security-Policy": CONTENT_SECURITY_POLICY,
    "Cache-Control": "no-store",
    "Referrer-Policy": "no-referrer",
    "X-Content-Type-Options": "nosniff",
}


DATA_HEADERS = {"Cache-Control": "no-store", "X-Content-Type-Options": "nosniff"}


def _job_id(job_id: str) -> None:
    """404 unless ``job_id`` is a job id in form."""
    try:
        uuid.UUID(job_id)
    except ValueError:
        raise ApiProblem(404, f"no job {job_id!r}", slug="not-found") from None


def _built() -> None:
    try:
        bundle()
    except ViewerNotBuilt as error:
        raise ApiProblem(503, str(error), slug="viewer-not-built") from None


@router.get("/viewer/{job_id}", response_class=HTMLResponse)
def viewer_page(job_id: str) -> HTMLResponse:
    """The viewer page of job ``job_id`` (404 unless it is a job id in form; whether the job
    exists and belongs to the caller is checked when the page fetches its artifacts)."""
    _job_id(job_id)
    _built()
    artifacts = [f"/v1/jobs/{job_id}/artifacts/{name}" for name in SEGMENT_FILES]
    config = ViewerConfig(
        title=f"job {job_id}",
        files=ViewerFiles(*artifacts),
        static="/viewer/static",
        frame=f"/viewer/{job_id}/{FRAME_FILE}",
    )
    return HTMLResponse(render_page(config), headers=PAGE_HEADERS)


@router.get("/viewer/static/{name}", response_class=FileResponse)
def viewer_static(name: str) -> FileResponse:
    """``viewer.js`` (the bundle) or ``viewer.css``."""
    _built()
    path = static_file(name)
    if path is None:
        raise ApiProblem(404, f"no viewer file {name!r}", slug="not-found")
    headers = {"Cache-Control": "no-cache", "X-Content-Type-Options": "nosniff"}
    return FileResponse(path, media_type=STATIC_FILES[name], headers=headers)


@router.get(f"/viewer/{{job_id}}/{FRAME_FILE}", response_class=Response)
def viewer_frame(job_id: str, state: StateDep, tenant: TenantDep) -> Response:
    """The job's ``frame.json`` (its up axis sets the camera's), found or derived as
    ``dcseg view`` does; the caller's key is checked as for the job's artifacts (401, 404 for
    another tenant's job, 409 for an unfinished one)."""
    _job_id(job_id)
    files = finished_job(state.storage, tenant, state.store.get_job(job_id, tenant), job_id)
    body = job_frame(files, state.settings)
    return Response(body, media_type="application/json", headers=DATA_HEADERS)
