"""Request and response bodies of the HTTP API (pydantic); the OpenAPI schema comes from here."""

from __future__ import annotations

import dataclasses
from datetime import datetime
from typing import TYPE_CHECKING, Annotated, Any, Literal, get_type_hints

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    RootModel,
    create_model,
    model_validator,
)

from dcseg.io.instance_record import InstanceRecord
from dcseg.options import JobOptions, PresetName

JobStatus = Literal["queued", "running", "canceling", "succeeded", "failed", "canceled"]
"""Job statuses (``jobstore.contract.ACTIVE`` then ``TERMINAL``; a test keeps them equal);
clients must tolerate values added later."""

TerminalStatus = Literal["succeeded", "failed", "canceled"]
"""The statuses a job never leaves (``jobstore.contract.TERMINAL``)."""


_PORT = r"(?:6553[0-5]|655[0-2][0-9]|65[0-4][0-9]{2}|6[0-4][0-9]{3}|[1-5][0-9]{4}|[0-9]{1,4})"
CALLBACK_URL = rf"^https?://[A-Za-z0-9._-]+(?::{_PORT})?(?:[/?#]\S*)?$"
"""What a callback URL looks like (in the schema, so clients and fuzzers know): http or https,
a host name or IPv4 address (IDN hosts in their ``xn--`` form), an optional port, no user."""


class JobCreate(BaseModel):
    """``POST /v1/jobs``: run the pipeline on an upload, or derive a job from a finished one."""

    model_config = ConfigDict(
        extra="forbid",
        allow_inf_nan=False,
        # "upload_id or parent_job_id" as a ``not``: an ``anyOf`` of two partial schemas is
        # read by SDK generators as two body types that lose the other fields
        json_schema_extra={
            "not": {
                "properties": {
                    "upload_id": {"type": "null"},
                    "parent_job_id": {"type": "null"},
                }
            }
        },
    )

    upload_id: str | None = Field(default=None, max_length=64)
    """The upload holding the capture and masks (``POST /v1/uploads``)."""

    parent_job_id: str | None = Field(default=None, max_length=64)
    """A succeeded job whose finished stages are reused when their parameters are unchanged;
    its upload is used when ``upload_id`` is omitted."""

    preset: PresetName = "fast"
    """Named parameter set (``fast``, ``paper``); ``options`` override single fields."""

    options: JobOptions = Field(default_factory=JobOptions)
    """Method parameters, each bounded (``dcseg.options``); the same builder as the CLI and the
    worker checks them, so a job the API accepts never fails on its options later."""

    callback_url: str | None = Field(default=None, max_length=2048, pattern=CALLBACK_URL)
    """An ``http``/``https`` URL (a host name or IPv4 address, no user or password) the job's
    JSON (as ``GET /v1/jobs/{job_id}``) is POSTed to when the job ends, signed
    (``X-Dcseg-Signature``, see the service README). A host that does not resolve, or resolves
    to a private, loopback, link-local, multicast or reserved address, is refused unless the
    server allows it (``DCSEG_WEBHOOK_ALLOW_PRIVATE``)."""

    @model_validator(mode="after")
    def _has_input(self) -> JobCreate:
        if self.upload_id is None and self.parent_job_id is None:
            raise ValueError("give upload_id or parent_job_id")
        return self


class Progress(BaseModel):
    stage: str | None
    stage_index: int
    """0-based index of the current stage."""
    stage_count: int
    fraction: float
    """Overall fraction done, 0 to 1."""
    message: str | None


class JobLinks(BaseModel):
    self: str
    cancel: str
    events: str
    artifacts: str


class JobPublic(BaseModel):
    id: str
    status: JobStatus
    """queued, running or canceling until the job ends succeeded, failed or canceled (more
    may be added)."""
    stage: str | None
    progress: Progress
    error: dict[str, Any] | None
    config: dict[str, Any]
    upload_id: str
    parent_job_id: str | None
    created_at: datetime
    started_at: datetime | None
    updated_at: datetime
    completed_at: datetime | None
    links: JobLinks


DeliveryState = Literal["pending", "delivered", "failed"]
"""A webhook delivery's state (``jobstore.models.WebhookDelivery.state``)."""


class WebhookAttemptPublic(BaseModel):
    attempt: int
    """1 for the first POST, then 2, 3..."""
    attempted_at: datetime
    status_code: int | None
    """The receiver's HTTP status; None when no answer came (see ``error``)."""
    error: str | None
    """Why the attempt failed (connection refused, timeout, a non-2xx status); None on 2xx."""


class WebhookDeliveryPublic(BaseModel):
    id: int
    url: str
    job_status: TerminalStatus
    """The status the job ended with (the body sent is the job as it is at each attempt)."""
    state: DeliveryState
    """``pending`` until a 2xx answer (``delivered``) or the last attempt failed."""
    next_attempt_at: datetime | None
    """When a pending delivery is tried next; None once it is delivered or failed."""
    created_at: datetime
    completed_at: datetime | None
    attempts: list[WebhookAttemptPublic]


class WebhookDeliveriesPublic(BaseModel):
    """``GET /v1/jobs/{job_id}/webhook-deliveries``: the job's webhooks (at most one per job
    today: it ends once) and every attempt of each."""

    deliveries: list[WebhookDeliveryPublic]


class JobsPublic(BaseModel):
    jobs: list[JobPublic]
    next_page_token: str | None = None
    """Absent on the last page."""


class UploadLinks(BaseModel):
    self: str


class UploadPublic(BaseModel):
    id: str
    sha256: str
    size: int
    content_type: str
    summary: dict[str, Any]
    """What ``dcseg validate`` reports: frames, resolution, depth range, masks, classes."""
    created_at: datetime
    links: UploadLinks


ArchiveType = Literal[
    "application/zip", "application/x-tar", "application/gzip", "application/x-gzip"
]


class DirectUploadCreate(BaseModel):
    """``POST /v1/direct-uploads``: an archive the client sends straight to object storage."""

    model_config = ConfigDict(extra="forbid")

    content_type: ArchiveType
    size: int = Field(ge=1, description="the archive's exact size in bytes")
    sha256: str | None = Field(
        default=None, pattern="^[0-9a-f]{64}$", description="expected SHA-256 (hex)"
    )


class DirectUploadPart(BaseModel):
    part_number: int
    url: str
    """Presigned ``PUT`` of this part (send bytes ``(n-1)*part_size`` up to ``n*part_size``);
    keep the response's ``ETag``."""


class DirectUploadLinks(BaseModel):
    complete: str


class DirectUploadPublic(BaseModel):
    id: str
    """The id the upload will have once completed (``/v1/uploads/{id}``)."""
    content_type: str
    size: int
    part_size: int
    parts: list[DirectUploadPart]
    expires_at: datetime
    """The part URLs stop working then; start again with a new direct upload."""
    links: DirectUploadLinks


class CompletedPart(BaseModel):
    model_config = ConfigDict(extra="forbid")

    part_number: int = Field(ge=1, le=10_000)
    etag: str = Field(min_length=1, max_length=200)


class DirectUploadComplete(BaseModel):
    model_config = ConfigDict(extra="forbid")

    parts: list[CompletedPart] = Field(min_length=1, max_length=10_000)


class ArtifactPublic(BaseModel):
    name: str
    """Path relative to the job's output folder, e.g. ``reconstruct/scene.ply``."""
    media_type: str
    size: int
    sha256: str
    url: str
    """The download through the API (``Range``, ``ETag``; needs the API key)."""
    download_url: str | None = None
    """Object storage only: a presigned URL that downloads the file straight from the store,
    without the API key, until ``download_url_expires_at``; None with local storage."""
    download_url_expires_at: datetime | None = None


class ArtifactsPublic(BaseModel):
    artifacts: list[ArtifactPublic]


class Health(BaseModel):
    status: Literal["ok"]
    """``ok``: a failed ``/readyz`` check answers a ``not-ready`` problem instead."""
    checks: dict[str, str] = Field(default_factory=dict)


class InstanceLinks(BaseModel):
    self: str
    exports: dict[str, str] = Field(default_factory=dict)
    """Export format -> the URL of this object's export in that format."""


REQUIRED_RECORD_FIELDS = (
    "id",
    "label",
    "label_id",
    "score",
    "n_gaussians",
    "centroid",
    "bbox_min",
    "bbox_max",
)
"""The fields of :class:`InstanceRecord` the API has required since its first version. The
others (``n_views`` and any field the record gains later) are optional, None when a job's
``instances.json`` lacks them, so objects of jobs made before a field existed still list."""


def instance_fields() -> dict[str, Any]:
    """``create_model`` definitions of :class:`InstancePublic`'s fields before ``links``:
    :class:`InstanceRecord`'s (in its order), the required ones first, then ``size``, then the
    optional ones (the order responses have always had)."""
    hints = get_type_hints(InstanceRecord)
    names = [field.name for field in dataclasses.fields(InstanceRecord)]
    required = {name: (hints[name], ...) for name in names if name in REQUIRED_RECORD_FIELDS}
    optional = {name: (hints[name] | None, None) for name in names if name not in required}
    # size: extent of the axis-aligned box per world axis (bbox_max - bbox_min, metres)
    return {**required, "size": (list[float], ...), **optional}


# An ``instances.json`` record and its size as a model, the record's fields taken from their one
# declaration (type checkers see a plain BaseModel: they cannot follow create_model).
if TYPE_CHECKING:
    InstanceFields = BaseModel
else:
    InstanceFields = create_model("InstanceFields", **instance_fields())


class InstancePublic(InstanceFields):
    """One segmented object: its record in ``segment/instances.json`` plus its size and links.

    Fields ``instances.json`` gains later are passed through unchanged."""

    model_config = ConfigDict(extra="allow")

    links: InstanceLinks


class InstancesPublic(BaseModel):
    instances: list[InstancePublic]
    next_page_token: str | None = None
    """Absent on the last page."""
    scene_sha256: str | None = None
    """SHA-256 of the ``scene_labelled.ply`` whose ``instance_id`` column the ids index."""


ExportFormat = Literal["ply", "spz", "splat", "glb", "glb-mesh", "obj", "usdz"]
"""Export formats: those of ``dcseg.export.FORMATS`` (a test keeps them equal)."""


ExportColour = Literal["instance", "class"]
"""Palette colours of an export: by object or by class (``dcseg.export.ExportOptions``)."""


class ExportLinks(BaseModel):
    self: str


class ExportPublic(BaseModel):
    """An export of a job (the whole scene or one instance) in one format."""

    format: str
    instance: int | None
    """The object exported alone; None = the whole scene."""
    options: dict[str, str | int]
    """The export options asked for (``colour``, ``sh_degree``); empty = the defaults."""
    status: Literal["succeeded", "running"]
    """``running``: the export is being made (202); ask again after ``Retry-After``."""
    files: list[ArtifactPublic]
    """The export's files (empty while it runs), downloaded like artifacts (ETag, Range)."""
    links: ExportLinks


class StatusEventData(BaseModel):
    """``event: status``: the job changed status (queued, started, cancel asked)."""

    model_config = ConfigDict(extra="allow")

    status: JobStatus
    message: str | None = None


class ProgressEventData(BaseModel):
    """``event: progress``: a stage reported progress (as ``JobPublic.progress``)."""

    model_config = ConfigDict(extra="allow")

    stage: str
    stage_index: int
    """0-based index of the stage."""
    stage_count: int
    fraction: float
    """Overall fraction done, 0 to 1."""
    message: str | None = None


class LogEventData(BaseModel):
    """``event: log``: a line of the worker's log, with the stage it belongs to."""

    model_config = ConfigDict(extra="allow")

    message: str
    stage: str | None = None


class CompletedEventData(BaseModel):
    """``event: completed``: the job ended; the last event of the stream."""

    model_config = ConfigDict(extra="allow")

    status: TerminalStatus
    message: str | None = None
    error: dict[str, Any] | None = None
    """The failure (``type``, ``detail``, more), as ``JobPublic.error``; None on success."""


class StatusEvent(BaseModel):
    event: Literal["status"]
    id: int
    """The job's event number (send it back as ``Last-Event-ID``)."""
    data: StatusEventData


class ProgressEvent(BaseModel):
    event: Literal["progress"]
    id: int
    data: ProgressEventData


class LogEvent(BaseModel):
    event: Literal["log"]
    id: int
    data: LogEventData


class CompletedEvent(BaseModel):
    event: Literal["completed"]
    id: int
    data: CompletedEventData


class JobEvent(RootModel[StatusEvent | ProgressEvent | LogEvent | CompletedEvent]):
    """One server-sent event of ``GET /v1/jobs/{job_id}/events``: its ``event:`` line names
    the type, ``id:`` its number and ``data:`` holds the JSON the type's schema describes.
    (OpenAPI 3.1 has no item schema for event streams; this is what 3.2 calls ``itemSchema``.)"""

    root: Annotated[
        StatusEvent | ProgressEvent | LogEvent | CompletedEvent, Field(discriminator="event")
    ]
