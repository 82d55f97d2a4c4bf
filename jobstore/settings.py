"""Deployment settings from the environment (prefix ``DCSEG_``), shared by API and workers.

Method parameters never live here: they travel with each job (see ``service.schemas``).
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path
from typing import Literal

from pydantic import Field, SecretStr, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

GIB = 2**30
REDIS_SCHEMES = ("redis://", "rediss://")


class Settings(BaseSettings):
    """Every deployment knob; each field reads ``DCSEG_<FIELD NAME>`` from the environment."""

    model_config = SettingsConfigDict(env_prefix="DCSEG_", extra="ignore")

    storage_dir: Path = Path("./dcseg-data")
    """Uploads and job artifacts; shared by the API and every worker."""

    storage_backend: Literal["local", "s3"] = "local"
    """Where uploads, stage outputs, manifests and artifacts live: ``local`` = under
    :attr:`storage_dir` (shared by API and workers), ``s3`` = an S3-compatible bucket
    (:attr:`s3_bucket`); then ``storage_dir`` only holds the API's temporary upload folders
    (and the default SQLite database) and each worker works in its own :attr:`scratch_dir`."""

    s3_endpoint_url: str | None = None
    """S3 endpoint (``http://seaweedfs:8333``, ``https://s3.eu-west-1.amazonaws.com``); None =
    the AWS default for :attr:`s3_region`. Always addressed path-style
    (``<endpoint>/<bucket>/<key>``)."""

    s3_public_endpoint_url: str | None = None
    """The endpoint clients reach for presigned URLs when it differs from :attr:`s3_endpoint_url`
    (an internal host name in compose, say); None = the same."""

    s3_bucket: str = "dcseg"
    """The bucket (created at API startup if missing)."""

    s3_prefix: str = ""
    """Key prefix inside the bucket (``dcseg/`` to share a bucket); each tenant's objects are
    under ``<prefix>tenants/<tenant>/``."""

    s3_region: str = "us-east-1"
    """Region used for request signing."""

    s3_access_key_id: SecretStr | None = None
    """Access key; None = boto3's default credential chain (``AWS_*`` variables, instance role)."""

    s3_secret_access_key: SecretStr | None = None
    """Secret key (never shown by ``repr``/logs)."""

    presign_expiry_s: int = Field(default=300, ge=1, le=7 * 24 * 3600)
    """Lifetime of presigned artifact download URLs and direct-upload part URLs (S3 only)."""

    direct_upload_part_bytes: int = Field(default=64 * 2**20, ge=5 * 2**20)
    """Part size of a presigned multipart upload (S3's minimum part is 5 MiB)."""

    scratch_dir: Path = Path("./dcseg-scratch")
    """S3 mode: the worker's private scratch folder (inputs and finished stages are fetched
    here, one sub-folder per job, removed when the job stops)."""

    scratch_max_bytes: int = Field(default=50 * GIB, ge=1)
    """S3 mode: most bytes one job may fetch and write in the worker's scratch folder (the
    archive, its extraction, finished stages' files and the stage being run); past it the job
    fails with a message naming this setting."""

    database_url: str | None = None
    """SQLAlchemy URL of the job store; None = ``sqlite:///<storage_dir>/dcseg.db``.
    PostgreSQL: ``postgresql+psycopg://user@host:5432/dbname``."""

    broker_url: str | None = None
    """Celery broker (``redis://host:6379/0``); None = embedded mode (a local worker)."""

    embedded_worker: Literal["process", "thread", "off"] = "process"
    """How ``dcseg serve`` runs jobs in embedded mode: a child process (default), a thread of
    the API process (tests), or not at all."""

    max_upload_bytes: int = Field(default=2 * GIB, ge=1)
    """Largest accepted upload body; larger bodies answer 413."""

    max_upload_validations: int = Field(default=2, ge=1)
    """Uploads extracted and validated at the same time, on threads of their own (never the
    threadpool that serves the other routes); further admitted uploads wait their turn."""

    max_pending_uploads: int = Field(default=16, ge=1)
    """Uploads one API process handles at once (receiving, waiting or validating); more
    answer 503 with ``Retry-After`` before their body is read."""

    tenant_storage_quota_bytes: int = Field(default=100 * GIB, ge=0)
    """Storage per tenant: extracted uploads plus job outputs; an upload that would exceed it
    answers 507. 0 = no quota."""

    min_free_bytes: int = Field(default=GIB, ge=0)
    """Free space the storage volume must keep; an upload that would leave less answers 507."""

    upload_expiry_s: float = Field(default=7 * 24 * 3600.0, ge=0)
    """An upload no job refers to is deleted this long after it was created. 0 = never."""

    idempotency_ttl_s: float = Field(default=24 * 3600.0, gt=0)
    """How long an ``Idempotency-Key`` is remembered; an older record is ignored and swept."""

    idempotency_in_flight_s: float = Field(default=3600.0, gt=0)
    """How long a keyed request that has not answered yet blocks its key (409); after that it
    counts as abandoned (its API process died) and a retry with the key runs again. Longer
    than the slowest upload validation."""

    housekeeping_interval_s: float = Field(default=600.0, gt=0)
    """How often the API deletes expired uploads and idempotency records."""

    max_extracted_bytes: int = Field(default=8 * GIB, ge=1)
    """Largest total size an uploaded archive may expand to."""

    max_archive_entries: int = Field(default=100_000, ge=1)
    """Largest number of entries in an uploaded archive."""

    max_archive_directory_bytes: int = Field(default=64 * 2**20, ge=1)
    """Largest central directory of an uploaded zip (its entry count and directory size are
    read from the end record first, so a bigger directory is refused before it is read)."""

    max_archive_header_bytes: int = Field(default=2**20, ge=512)
    """Largest pax or GNU long-name header record of one member of an uploaded tar."""

    max_validation_pixels: int = Field(default=2_000_000_000, ge=1)
    """Largest total number of pixels upload validation may decode (colour, depth, masks and
    class maps together), summed from the image headers before anything is decoded."""

    api_keys: SecretStr = SecretStr("")
    """``tenant:key`` pairs separated by commas, or ``@/path/file`` with one pair per line
    (``#`` starts a comment). Secret: ``repr``/``str``/logging of the settings never show it.
    No pairs (empty, or a file of comments) = no authentication: every request belongs to
    tenant ``local`` and, unless :attr:`allow_unauthenticated`, only loopback is served."""

    allow_unauthenticated: bool = False
    """With no API keys: False (default) serves only loopback clients that name the server by
    a loopback ``Host`` (``localhost``, ``127.0.0.0/8``, ``[::1]``; others answer 403/421, which
    stops DNS rebinding) and ``dcseg serve`` refuses a non-loopback ``--host``; True serves
    everyone as tenant ``local``. Ignored when keys are configured."""

    min_api_key_length: int = Field(default=16, ge=1)
    """Shortest accepted API key; a shorter one stops startup with an error naming its tenant."""

    rate_limit_url: str | None = None
    """Redis URL of the rate limiter shared by every API replica; None = :attr:`broker_url` when
    it is a ``redis://``/``rediss://`` URL, else per process; ``memory`` = per process."""

    rate_limit_key_prefix: str = "dcseg:ratelimit:"
    """Prefix of the shared limiter's Redis keys."""

    failed_auth_per_minute: int = Field(default=30, ge=1)
    """Requests with a missing or wrong API key per client address per minute; past it every
    request from that address answers 429 until the minute ends (stops key guessing)."""

    max_streams_per_tenant: int = Field(default=8, ge=1)
    """Open event streams (``GET /v1/jobs/{id}/events``) per tenant and API process; more
    answer 429."""

    max_stream_s: float = Field(default=900.0, gt=0)
    """Longest life of one event stream; it then ends cleanly and the client reconnects with
    ``Last-Event-ID`` (browsers' EventSource do so by themselves)."""

    stream_poll_max_s: float = Field(default=5.0, gt=0)
    """Longest pause between store polls of an idle event stream: the pause starts at
    :attr:`poll_interval_s` and doubles while nothing happens."""

    max_running_jobs_per_tenant: int = Field(default=4, ge=1)
    """Unfinished (queued, running, canceling) jobs a tenant may have; more answer 429."""

    max_attempts: int = Field(default=3, ge=1)
    """Runs a job may start. A worker that dies mid-job (OOM kill, segfault) leaves its job to
    be claimed again; after this many claims the job fails (``too-many-attempts``) instead of
    being requeued forever. Runs stopped by a worker shutdown do not count."""

    sqlite_busy_timeout_s: float | None = Field(default=None, gt=0)
    """How long a SQLite write waits for another writer's lock before failing; None = half of
    ``heartbeat_s``. Must be below the stale-lease window ``3 * heartbeat_s``, so a heartbeat
    stuck behind a lock fails and retries instead of letting a live lease look dead (with half
    an interval, a beat that waited the whole timeout still retries at 1.5 intervals)."""

    @property
    def busy_timeout_s(self) -> float:
        """The effective SQLite busy timeout (:attr:`sqlite_busy_timeout_s`)."""
        return self.sqlite_busy_timeout_s or self.heartbeat_s / 2

    @model_validator(mode="after")
    def _busy_timeout_below_stale_lease(self) -> Settings:
        if self.busy_timeout_s >= 3 * self.heartbeat_s:
            raise ValueError(
                f"sqlite_busy_timeout_s (DCSEG_SQLITE_BUSY_TIMEOUT_S = {self.busy_timeout_s:g} s)"
                " must be smaller than the stale-lease window 3 * heartbeat_s"
                f" (DCSEG_HEARTBEAT_S = {self.heartbeat_s:g} s: {3 * self.heartbeat_s:g} s)"
            )
        return self

    rate_limit_per_minute: int = Field(default=600, ge=1)
    """Requests per tenant per minute (shared by the replicas through Redis, see
    :attr:`rate_limit_url`, else per API process); more answer 429."""

    retry_after_s: int = Field(default=2, ge=1)
    """``Retry-After`` sent with unfinished jobs."""

    poll_interval_s: float = Field(default=0.5, gt=0)
    """How often the embedded worker and event streams poll the store."""

    heartbeat_s: float = Field(default=10.0, gt=0)
    """How often a running job's worker refreshes its lease; a job whose heartbeat is older
    than three intervals may be claimed by another delivery."""

    sweep_interval_s: float = Field(default=30.0, gt=0)
    """How often the API requeues running jobs whose worker stopped heartbeating (a killed
    worker's job is picked up again after about ``3 * heartbeat_s + sweep_interval_s``) and
    re-sends queued jobs if the broker lost its messages (Redis restarted without persistence)."""

    gpu_queue: str = "gpu"
    """Celery queue of the pipeline task."""

    visibility_timeout_s: int = Field(default=12 * 3600, ge=60)
    """Redis visibility timeout: an unacknowledged task is redelivered after this long. Must
    exceed the longest queue wait plus run time, or long jobs get delivered twice."""

    task_soft_time_limit_s: int = Field(default=10 * 3600, ge=1)
    """Celery soft time limit of one job (raises inside the task); at least the sum of the
    stage limits (checked), so every stage can use its own limit."""

    task_time_limit_s: int = Field(default=10 * 3600 + 300, ge=1)
    """Celery hard time limit of one job (the worker child is killed; prefork pool only);
    above the soft limit and below the visibility timeout (checked)."""

    stage_time_limit_s: dict[str, float] = {
        "validate": 900.0,
        "reconstruct": 5 * 3600.0,
        "train": 3 * 3600.0,
        "segment": 3600.0,
    }
    """Per-stage limit in seconds (JSON object, stage name -> seconds); a stage over it fails
    the job. Checked at each progress report; a stage that reports none is stopped
    ``stage_kill_grace_s`` after its limit."""

    stage_time_limit_default_s: float = Field(default=3600.0, gt=0)
    """Limit of a stage that ``stage_time_limit_s`` does not name."""

    @model_validator(mode="after")
    def _time_limits_fit(self) -> Settings:
        bad = {k: v for k, v in self.stage_time_limit_s.items() if not 0 < v < float("inf")}
        if bad:
            raise ValueError(f"stage_time_limit_s (DCSEG_STAGE_TIME_LIMIT_S) must be > 0: {bad}")
        total = sum(self.stage_time_limit_s.values())
        if total > self.task_soft_time_limit_s:
            raise ValueError(
                f"the stage limits (DCSEG_STAGE_TIME_LIMIT_S) add up to {total:g} s, more than"
                f" DCSEG_TASK_SOFT_TIME_LIMIT_S = {self.task_soft_time_limit_s} s"
            )
        if not self.task_soft_time_limit_s < self.task_time_limit_s < self.visibility_timeout_s:
            raise ValueError(
                "DCSEG_TASK_SOFT_TIME_LIMIT_S < DCSEG_TASK_TIME_LIMIT_S <"
                " DCSEG_VISIBILITY_TIMEOUT_S must hold (a job still running at the visibility"
                " timeout is delivered twice)"
            )
        return self

    stage_kill_grace_s: float = Field(default=60.0, gt=0)
    """How long a stage may run past its limit without reaching a progress report before it
    is stopped by force: the job fails, and the worker process is killed where that is safe
    (embedded ``process`` mode, Celery prefork pool child) or the stage is abandoned (thread
    mode, Celery ``solo``/``threads`` pools)."""

    shutdown_grace_s: float = Field(default=8.0, gt=0)
    """The API's shutdown deadline. ``dcseg serve`` gives open responses this long (event
    streams end at once; plain uvicorn needs ``--timeout-graceful-shutdown``), then the app's
    shutdown waits at most this long, for the recovery sweep, housekeeping and the embedded
    worker together: the worker's job stops at its next progress report (it stays unfinished,
    keeps its attempt and resumes from its last finished stage at the next start), else the
    worker process is killed (plus up to 5 s to reap it). So shutdown takes at most about
    ``2 * shutdown_grace_s + 5`` s: give the container a longer stop timeout than that
    (Docker's default is 10 s)."""

    device: str = "auto"
    """Worker device: ``auto`` (CUDA when available), ``cpu``, ``cuda``, ``cuda:1``..."""

    export_time_limit_s: float = Field(default=600.0, gt=0)
    """Longest an on-demand export (``/exports/{format}``) may run; its process is then killed
    and the export fails (``export-timed-out``, cached until this limit changes)."""

    max_export_bytes: int = Field(default=2 * GIB, ge=1)
    """Largest total size of one export's files; a larger one is discarded and fails
    (``export-too-large``)."""

    max_concurrent_exports: int = Field(default=2, ge=1)
    """Exports one API process makes at once (one child process each); more wait in line."""

    export_wait_s: float = Field(default=20.0, ge=0)
    """How long an export request waits for the export to be made before answering 202 with
    ``Retry-After`` (the export goes on; ask again)."""

    webhook_secret: SecretStr = SecretStr("")
    """Key of the webhooks' HMAC-SHA256 signature (``X-Dcseg-Signature``); never shown by
    ``repr``/logs. Empty (default) = webhooks are off: a job naming a ``callback_url`` answers
    422."""

    webhook_allow_private: bool = False
    """Accept callback URLs whose host resolves to a private, loopback, link-local, multicast
    or reserved address (refused by default: the API must not be a way into its own network).
    Checked when the job is submitted and again before every delivery."""

    webhook_max_attempts: int = Field(default=8, ge=1)
    """POSTs of one webhook before it is given up (``failed``); a connection error, a timeout
    or a non-2xx answer is retried."""

    webhook_backoff_s: float = Field(default=10.0, gt=0)
    """Wait after a webhook's first failed attempt; it doubles after each further failure."""

    webhook_backoff_max_s: float = Field(default=3600.0, gt=0)
    """Longest wait between two attempts of a webhook."""

    webhook_timeout_s: float = Field(default=10.0, gt=0)
    """How long one webhook POST may take (connect plus answer)."""

    webhook_poll_s: float = Field(default=1.0, gt=0)
    """How often the API's webhook dispatcher looks for due deliveries."""

    webhook_lease_s: float = Field(default=60.0, gt=0)
    """How long a dispatcher holds the deliveries it claimed: another API process sends them
    only after this (its holder died). Must exceed :attr:`webhook_timeout_s` (checked)."""

    @model_validator(mode="after")
    def _webhook_lease_above_timeout(self) -> Settings:
        if self.webhook_lease_s <= self.webhook_timeout_s:
            raise ValueError(
                "DCSEG_WEBHOOK_LEASE_S must exceed DCSEG_WEBHOOK_TIMEOUT_S (a delivery still "
                "being sent would be sent again by another API process)"
            )
        return self

    @property
    def db_url(self) -> str:
        """The effective database URL."""
        if self.database_url:
            return self.database_url
        return f"sqlite:///{self.storage_dir.resolve() / 'dcseg.db'}"

    @property
    def effective_rate_limit_url(self) -> str | None:
        """The Redis URL of the shared rate limiter, or None for per-process limits."""
        url = self.rate_limit_url
        if url is None and self.broker_url and self.broker_url.startswith(REDIS_SCHEMES):
            url = self.broker_url
        return None if url in (None, "", "memory") else url

    def parsed_api_keys(self) -> dict[str, str]:
        """``{key: tenant}`` from :attr:`api_keys`; ValueError (naming the tenant, never the
        key) for a malformed entry or a key shorter than :attr:`min_api_key_length`."""
        text = self.api_keys.get_secret_value().strip()
        if text.startswith("@"):
            text = Path(text[1:]).read_text(encoding="utf-8")
        pairs: dict[str, str] = {}
        for item in text.replace("\n", ",").split(","):
            item = item.strip()
            if not item or item.startswith("#"):
                continue
            tenant, sep, key = (part.strip() for part in item.partition(":"))
            if not sep or not tenant or not key:
                raise ValueError("DCSEG_API_KEYS entries must look like tenant:key")
            if len(key) < self.min_api_key_length:
                raise ValueError(
                    f"DCSEG_API_KEYS: the key of tenant {tenant!r} has {len(key)} characters; "
                    f"keys need at least {self.min_api_key_length} (DCSEG_MIN_API_KEY_LENGTH)"
                )
            pairs[key] = tenant
        return pairs


@lru_cache
def get_settings() -> Settings:
    """The process-wide settings (tests pass their own ``Settings`` to ``create_app``)."""
    return Settings()
