"""``/v1/jobs/{id}/exports/{format}`` and ``/instances/{k}/exports/{format}``: made on demand,
cached in the job's folder, downloaded like artifacts (``/{name}``, ETag and Range)."""

from __future__ import annotations

import asyncio
from dataclasses import dataclass
from pathlib import Path as FilePath
from typing import Annotated, Any
from urllib.parse import urlencode

from fastapi import APIRouter, Depends, Path, Query, Request, Response
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse, StreamingResponse

from jobstore.blobstore import StoredFile, read_local
from service import artifacts, exports, instances
from service.deps import AppState, StateDep, TenantDep
from service.problems import ApiProblem, problem_responses
from service.routes.artifacts import (
    IfNoneMatch,
    IfRange,
    RangeHeader,
    Reader,
    send_file,
    send_headers,
)
from service.routes.instances import InstanceId, instance_url
from service.schemas import ArtifactPublic, ExportColour, ExportFormat, ExportLinks, ExportPublic

router = APIRouter(prefix="/v1/jobs", tags=["exports"])

Format = Annotated[ExportFormat, Path(alias="format", description="export format")]


def get_exporter(request: Request) -> exports.Exporter:
    exporter: exports.Exporter = request.app.state.exporter
    return exporter


ExporterDep = Annotated[exports.Exporter, Depends(get_exporter)]


def export_options(
    colour: Annotated[
        ExportColour | None,
        Query(description="palette colours by object or by class; default: as reconstructed"),
    ] = None,
    sh_degree: Annotated[
        int | None,
        Query(ge=0, le=3, description="write this SH degree (3 pads for strict loaders)"),
    ] = None,
) -> tuple[tuple[str, str | int], ...]:
    """The export options of the query (each one makes its own cached export)."""
    given: dict[str, str | int | None] = {"colour": colour, "sh_degree": sh_degree}
    return tuple(sorted((k, v) for k, v in given.items() if v is not None))


OptionsDep = Annotated[tuple[tuple[str, str | int], ...], Depends(export_options)]


def _path(job_id: str, selection: exports.Selection) -> str:
    if selection.instance is None:
        return f"/v1/jobs/{job_id}/exports/{selection.fmt}"
    return f"{instance_url(job_id, selection.instance)}/exports/{selection.fmt}"


def _query(selection: exports.Selection) -> str:
    return "?" + urlencode(selection.options) if selection.options else ""


def export_url(job_id: str, selection: exports.Selection) -> str:
    return _path(job_id, selection) + _query(selection)


@dataclass(frozen=True)
class Asked:
    """An export request as a route receives it: who asks, for which job, and what."""

    state: AppState
    tenant: str
    job_id: str
    selection: exports.Selection


def scene_asked(
    job_id: str, fmt: Format, options: OptionsDep, state: StateDep, tenant: TenantDep
) -> Asked:
    """The whole scene's export (``/{job_id}/exports/{format}``)."""
    return Asked(state, tenant, job_id, exports.Selection(fmt, None, options))


def instance_asked(
    job_id: str,
    k: InstanceId,
    fmt: Format,
    options: OptionsDep,
    state: StateDep,
    tenant: TenantDep,
) -> Asked:
    """One object's export (``/{job_id}/instances/{k}/exports/{format}``)."""
    return Asked(state, tenant, job_id, exports.Selection(fmt, k, options))


SceneAsked = Annotated[Asked, Depends(scene_asked)]
InstanceAsked = Annotated[Asked, Depends(instance_asked)]


def file_name(name: str) -> str:
    """The file of an export to download. A dependency rather than a route parameter so that
    the OpenAPI document lists it after ``format``: a route's own parameters come first."""
    return name


FileName = Annotated[str, Depends(file_name)]


@dataclass(frozen=True)
class Target:
    """A checked export request: the run to read and the cache folder."""

    asked: Asked
    run: exports.RunGetter
    folder: FilePath


def _target(asked: Asked) -> Target:
    """404 for an unknown job or instance, 409 for an unfinished job."""
    state, tenant, job_id, selection = asked.state, asked.tenant, asked.job_id, asked.selection
    job = state.store.get_job(job_id, tenant)
    files = instances.finished_job(state.storage, tenant, job, job_id)
    records = instances.read_instances(files).get("instances", [])
    if selection.instance is not None:
        instances.find_instance(records, job_id, selection.instance)
    run = exports.run_getter(state.storage, tenant, job_id, state.settings)
    folder = selection.folder(exports.cache_root(state.settings, job_id))
    return Target(asked, run, folder)


def _public(target: Target, done: exports.Done | None) -> dict[str, Any]:
    selection = target.asked.selection
    path, query = _path(target.asked.job_id, selection), _query(selection)
    files = [
        ArtifactPublic(
            name=f.name,
            media_type=_artifact(f).media_type,
            size=f.size,
            sha256=f.sha256,
            url=f"{path}/{f.name}{query}",
        )
        for f in (done.files if done else [])
    ]
    body = ExportPublic(
        format=selection.fmt,
        instance=selection.instance,
        options=dict(selection.options),
        status="succeeded" if done else "running",
        files=files,
        links=ExportLinks(self=path + query),
    )
    return body.model_dump(mode="json")


def _reader(found: artifacts.Artifact) -> Reader:
    """Exports are cached on the API's disk whatever the storage backend."""
    path = found.item.path
    assert path is not None
    return lambda start, end: read_local(path, start, end)


def _artifact(item: exports.ExportFile) -> artifacts.Artifact:
    return artifacts.Artifact(StoredFile(item.name, item.size, item.sha256, path=item.path))


def _failure(target: Target, failed: exports.Failed) -> ApiProblem:
    extensions: dict[str, Any] = {"job_id": target.asked.job_id}
    if failed.errors:
        extensions["errors"] = failed.errors
    status = 500 if failed.slug == "export-error" else 422
    return ApiProblem(status, failed.detail, slug=failed.slug, **extensions)


async def _serve(asked: Asked, exporter: exports.Exporter) -> Response:
    """The export's description: made (or being made, 202) on the first request, then cached."""
    settings, sel = asked.state.settings, asked.selection
    target = await run_in_threadpool(_target, asked)
    cached = await run_in_threadpool(exports.read_cached, target.folder, settings)
    if cached is None:
        making = exporter.start(target.run, target.folder, sel)
        waited = asyncio.wrap_future(making)
        try:
            uncached = await asyncio.wait_for(asyncio.shield(waited), settings.export_wait_s)
        except TimeoutError:
            headers = {
                "Retry-After": str(settings.retry_after_s),
                "Location": export_url(asked.job_id, sel),
            }
            return JSONResponse(_public(target, None), status_code=202, headers=headers)
        cached = await run_in_threadpool(exports.read_cached, target.folder, settings)
        cached = cached or uncached
    if isinstance(cached, exports.Failed):
        raise _failure(target, cached)
    if cached is None:
        raise ApiProblem(500, "the export left no result", slug="export-error", job_id=asked.job_id)
    return JSONResponse(_public(target, cached))


EXPORT_RESPONSES: dict[int | str, dict[str, Any]] = {
    202: {"model": ExportPublic, "description": "being made; ask again after Retry-After"},
    **problem_responses(401, 404, 409, 422, 500),
}


@router.get(
    "/{job_id}/exports/{format}",
    response_model=ExportPublic,
    responses=EXPORT_RESPONSES,
    operation_id="getSceneExport",
)
async def scene_export(asked: SceneAsked, exporter: ExporterDep) -> Response:
    """The whole scene in one format: made on the first request and cached. 202 with
    ``Retry-After`` while it is being made; 422 when the job cannot be exported so (or the
    export passed a limit), with the reason."""
    return await _serve(asked, exporter)


@router.get(
    "/{job_id}/instances/{k}/exports/{format}",
    response_model=ExportPublic,
    responses=EXPORT_RESPONSES,
    operation_id="getInstanceExport",
)
async def instance_export(asked: InstanceAsked, exporter: ExporterDep) -> Response:
    """One object alone in one format (made on demand and cached, as the scene's)."""
    return await _serve(asked, exporter)


def _file(asked: Asked, name: str) -> artifacts.Artifact:
    """A file of a made export; 404 before the export is made and for a name it lacks."""
    sel = asked.selection
    cached = exports.read_cached(_target(asked).folder, asked.state.settings)
    if not isinstance(cached, exports.Done):
        url = export_url(asked.job_id, sel)
        raise ApiProblem(404, f"no {sel.fmt} export made yet; GET {url} first", slug="not-found")
    found = next((f for f in cached.files if f.name == name), None)
    if found is None:
        raise ApiProblem(404, f"the {sel.fmt} export has no file {name!r}", slug="not-found")
    return _artifact(found)


def _download(
    asked: Asked,
    name: str,
    range_header: str | None,
    if_range: str | None,
    if_none_match: str | None,
) -> Response:
    """``GET`` of an export's file: as artifacts (ETag, ``Range``, ``If-Range``)."""
    found = _file(asked, name)
    return send_file(found, _reader(found), range_header, if_range, if_none_match)


def _head(asked: Asked, name: str, if_none_match: str | None) -> Response:
    """``HEAD`` of an export's file: the headers of a whole download, no body."""
    return send_headers(_file(asked, name), if_none_match)


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

# One route function per path and method: FastAPI names each operation's summary after its
# function, and a HEAD declared with its GET (``api_route``) would share the GET's
# operationId, summary and Range parameters in the OpenAPI document.


@router.get(
    SCENE_FILE,
    response_class=StreamingResponse,
    responses=FILE_RESPONSES,
    operation_id="downloadSceneExportFile",
)
def download_scene_export(
    asked: SceneAsked,
    name: FileName,
    range_header: RangeHeader = None,
    if_range: IfRange = None,
    if_none_match: IfNoneMatch = None,
) -> Response:
    """Download one file of a made scene export (ETag, ``Range``, as artifacts)."""
    return _download(asked, name, range_header, if_range, if_none_match)


@router.head(
    SCENE_FILE,
    response_class=Response,
    responses=HEAD_RESPONSES,
    operation_id="headSceneExportFile",
)
def scene_export_headers(
    asked: SceneAsked, name: FileName, if_none_match: IfNoneMatch = None
) -> Response:
    """The headers of a whole download of a scene export's file, no body."""
    return _head(asked, name, if_none_match)


@router.get(
    INSTANCE_FILE,
    response_class=StreamingResponse,
    responses=FILE_RESPONSES,
    operation_id="downloadInstanceExportFile",
)
def download_instance_export(
    asked: InstanceAsked,
    name: FileName,
    range_header: RangeHeader = None,
    if_range: IfRange = None,
    if_none_match: IfNoneMatch = None,
) -> Response:
    """Download one file of a made instance export (ETag, ``Range``, as artifacts)."""
    return _download(asked, name, range_header, if_range, if_none_match)


@router.head(
    INSTANCE_FILE,
    response_class=Response,
    responses=HEAD_RESPONSES,
    operation_id="headInstanceExportFile",
)
def instance_export_headers(
    asked: InstanceAsked, name: FileName, if_none_match: IfNoneMatch = None
) -> Response:
    """The headers of a whole download of an instance export's file, no body."""
    return _head(asked, name, if_none_match)
