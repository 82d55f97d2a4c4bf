"""``/v1/jobs/{id}/exports/{format}`` and ``/instances/{k}/exports/{format}``: made on demand,
cached in the job's folder, downloaded like artifacts (``/{name}``, ETag and Range)."""

from __future__ import annotations

import asyncio
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path as FilePath
from typing import Annotated, Any

from fastapi import APIRouter, Depends, Path, Request, Response
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse, StreamingResponse

from service import artifacts, exports, instances
from service.blobstore import StoredFile, read_local
from service.deps import AppState, StateDep, TenantDep
from service.problems import ApiProblem, problem_responses
from service.routes.artifacts import IfNoneMatch, IfRange, RangeHeader, send_file, send_headers
from service.routes.instances import InstanceId, instance_url
from service.schemas import ArtifactPublic, ExportFormat, ExportLinks, ExportPublic

router = APIRouter(prefix="/v1/jobs", tags=["exports"])

Format = Annotated[ExportFormat, Path(alias="format", description="export format")]


def get_exporter(request: Request) -> exports.Exporter:
    exporter: exports.Exporter = request.app.state.exporter
    return exporter


ExporterDep = Annotated[exports.Exporter, Depends(get_exporter)]


def export_url(job_id: str, selection: exports.Selection) -> str:
    if selection.instance is None:
        return f"/v1/jobs/{job_id}/exports/{selection.fmt}"
    return f"{instance_url(job_id, selection.instance)}/exports/{selection.fmt}"


@dataclass(frozen=True)
class Target:
    """A checked export request: the run to read and the cache folder."""

    job_id: str
    run: FilePath
    folder: FilePath
    selection: exports.Selection


def _target(state: AppState, tenant: str, job_id: str, selection: exports.Selection) -> Target:
    """404 for an unknown job or instance, 409 for an unfinished job."""
    paths = instances.finished_job(state.settings, state.store.get_job(job_id, tenant), job_id)
    records = instances.read_instances(state.storage, tenant, paths).get("instances", [])
    if selection.instance is not None:
        instances.find_instance(records, job_id, selection.instance)
    return Target(job_id, exports.run_folder(paths), selection.folder(paths.folder), selection)


def _public(target: Target, done: exports.Done | None) -> dict[str, Any]:
    url = export_url(target.job_id, target.selection)
    files = [
        ArtifactPublic(
            name=f.name,
            media_type=_artifact(f).media_type,
            size=f.size,
            sha256=f.sha256,
            url=f"{url}/{f.name}",
        )
        for f in (done.files if done else [])
    ]
    body = ExportPublic(
        format=target.selection.fmt,
        instance=target.selection.instance,
        status="succeeded" if done else "running",
        files=files,
        links=ExportLinks(self=url),
    )
    return body.model_dump(mode="json")


def _artifact(item: exports.ExportFile) -> artifacts.Artifact:
    return artifacts.Artifact(StoredFile(item.name, item.size, item.sha256, path=item.path))


def _send(
    found: artifacts.Artifact, range_header: str | None, if_range: str | None, inm: str | None
) -> Response:
    """Exports are files in the API's export cache folder, read locally."""
    path = found.item.path
    assert path is not None

    def read(start: int, end: int) -> Iterator[bytes]:
        return read_local(path, start, end)

    return send_file(found, read, range_header, if_range, inm)


def _failure(target: Target, failed: exports.Failed) -> ApiProblem:
    extensions: dict[str, Any] = {"job_id": target.job_id}
    if failed.errors:
        extensions["errors"] = failed.errors
    status = 500 if failed.slug == "export-error" else 422
    return ApiProblem(status, failed.detail, slug=failed.slug, **extensions)


async def _serve(
    state: AppState, tenant: str, exporter: exports.Exporter, job_id: str, sel: exports.Selection
) -> Response:
    target = await run_in_threadpool(_target, state, tenant, job_id, sel)
    cached = await run_in_threadpool(exports.read_cached, target.folder, state.settings)
    if cached is None:
        making = exporter.start(target.run, target.folder, sel)
        waited = asyncio.wrap_future(making)
        try:
            await asyncio.wait_for(asyncio.shield(waited), state.settings.export_wait_s)
        except TimeoutError:
            headers = {
                "Retry-After": str(state.settings.retry_after_s),
                "Location": export_url(job_id, sel),
            }
            return JSONResponse(_public(target, None), status_code=202, headers=headers)
        cached = await run_in_threadpool(exports.read_cached, target.folder, state.settings)
    if isinstance(cached, exports.Failed):
        raise _failure(target, cached)
    if cached is None:
        raise ApiProblem(500, "the export left no result", slug="export-error", job_id=job_id)
    return JSONResponse(_public(target, cached))


EXPORT_RESPONSES: dict[int | str, dict[str, Any]] = {
    202: {"model": ExportPublic, "description": "being made; ask again after Retry-After"},
    **problem_responses(401, 404, 409, 422, 500),
}


@router.get("/{job_id}/exports/{format}", response_model=ExportPublic, responses=EXPORT_RESPONSES)
async def scene_export(
    job_id: str, fmt: Format, state: StateDep, tenant: TenantDep, exporter: ExporterDep
) -> Response:
    """The whole scene in one format: made on the first request and cached. 202 with
    ``Retry-After`` while it is being made; 422 when the job cannot be exported so (or the
    export passed a limit), with the reason."""
    return await _serve(state, tenant, exporter, job_id, exports.Selection(fmt))


@router.get(
    "/{job_id}/instances/{k}/exports/{format}",
    response_model=ExportPublic,
    responses=EXPORT_RESPONSES,
)
async def instance_export(
    job_id: str,
    k: InstanceId,
    fmt: Format,
    state: StateDep,
    tenant: TenantDep,
    exporter: ExporterDep,
) -> Response:
    """One object alone in one format (made on demand and cached, as the scene's)."""
    return await _serve(state, tenant, exporter, job_id, exports.Selection(fmt, k))


def _file(
    state: AppState, tenant: str, job_id: str, sel: exports.Selection, name: str
) -> artifacts.Artifact:
    target = _target(state, tenant, job_id, sel)
    cached = exports.read_cached(target.folder, state.settings)
    if not isinstance(cached, exports.Done):
        url = export_url(job_id, sel)
        raise ApiProblem(404, f"no {sel.fmt} export made yet; GET {url} first", slug="not-found")
    found = next((f for f in cached.files if f.name == name), None)
    if found is None:
        raise ApiProblem(404, f"the {sel.fmt} export has no file {name!r}", slug="not-found")
    return _artifact(found)


FILE_RESPONSES: dict[int | str, dict[str, Any]] = {
    200: {"content": {"application/octet-stream": {}}, "description": "the file"},
    206: {"description": "Partial Content"},
    304: {"description": "Not Modified"},
    **problem_responses(401, 404, 409, 416, 422),
}
HEAD_RESPONSES: dict[int | str, dict[str, Any]] = {
    200: {"description": "the headers of the download, no body"},
    304: {"description": "Not Modified"},
    **problem_responses(401, 404, 409, 422),
}
SCENE_FILE = "/{job_id}/exports/{format}/{name:path}"
INSTANCE_FILE = "/{job_id}/instances/{k}/exports/{format}/{name:path}"


@router.get(SCENE_FILE, response_class=StreamingResponse, responses=FILE_RESPONSES)
def download_scene_export(
    job_id: str,
    fmt: Format,
    name: str,
    state: StateDep,
    tenant: TenantDep,
    range_header: RangeHeader = None,
    if_range: IfRange = None,
    if_none_match: IfNoneMatch = None,
) -> Response:
    """Download one file of a made scene export (ETag, ``Range``, as artifacts)."""
    found = _file(state, tenant, job_id, exports.Selection(fmt), name)
    return _send(found, range_header, if_range, if_none_match)


@router.head(SCENE_FILE, response_class=Response, responses=HEAD_RESPONSES)
def scene_export_headers(
    job_id: str,
    fmt: Format,
    name: str,
    state: StateDep,
    tenant: TenantDep,
    if_none_match: IfNoneMatch = None,
) -> Response:
    """The headers of a whole download of a scene export's file, no body."""
    found = _file(state, tenant, job_id, exports.Selection(fmt), name)
    return send_headers(found, if_none_match)


@router.get(INSTANCE_FILE, response_class=StreamingResponse, responses=FILE_RESPONSES)
def download_instance_export(
    job_id: str,
    k: InstanceId,
    fmt: Format,
    name: str,
    state: StateDep,
    tenant: TenantDep,
    range_header: RangeHeader = None,
    if_range: IfRange = None,
    if_none_match: IfNoneMatch = None,
) -> Response:
    """Download one file of a made instance export (ETag, ``Range``, as artifacts)."""
    found = _file(state, tenant, job_id, exports.Selection(fmt, k), name)
    return _send(found, range_header, if_range, if_none_match)


@router.head(INSTANCE_FILE, response_class=Response, responses=HEAD_RESPONSES)
def instance_export_headers(
    job_id: str,
    k: InstanceId,
    fmt: Format,
    name: str,
    state: StateDep,
    tenant: TenantDep,
    if_none_match: IfNoneMatch = None,
) -> Response:
    """The headers of a whole download of an instance export's file, no body."""
    found = _file(state, tenant, job_id, exports.Selection(fmt, k), name)
    return send_headers(found, if_none_match)
