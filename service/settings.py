"""Deployment settings from the environment (prefix ``DCSEG_``), shared by API and workers.

Method parameters never live here: they travel with each job (see ``service.schemas``).
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path
from typing import Literal

from pydantic import Field
from pydantic_settings import BaseSettings, SettingsConfigDict

GIB = 2**30


class Settings(BaseSettings):
    """Every deployment knob; each field reads ``DCSEG_<FIELD NAME>`` from the environment."""

    model_config = SettingsConfigDict(env_prefix="DCSEG_", extra="ignore")

    storage_dir: Path = Path("./dcseg-data")
    """Uploads and job artifacts; shared by the API and every worker."""

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

    housekeeping_interval_s: float = Field(default=600.0, gt=0)
    """How often the API deletes expired uploads and idempotency records."""

    max_extracted_bytes: int = Field(default=8 * GIB, ge=1)
    """Largest total size an uploaded archive may expand to."""

    max_archive_entries: int = Field(default=100_000, ge=1)
    """Largest number of entries in an uploaded archive."""

    api_keys: str = ""
    """``tenant:key`` pairs separated by commas, or ``@/path/file`` with one pair per line.
    Empty = no authentication, every request belongs to tenant ``local`` (``dcseg serve``
    refuses this unless it binds to a loopback address)."""

    max_running_jobs_per_tenant: int = Field(default=4, ge=1)
    """Unfinished (queued, running, canceling) jobs a tenant may have; more answer 429."""

    rate_limit_per_minute: int = Field(default=600, ge=1)
    """Requests per tenant per minute (per API process); more answer 429."""

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

    task_soft_time_limit_s: int = Field(default=6 * 3600, ge=1)
    """Celery soft time limit of one job (raises inside the task)."""

    task_time_limit_s: int = Field(default=6 * 3600 + 300, ge=1)
    """Celery hard time limit of one job (the worker child is killed; prefork pool only)."""

    stage_time_limit_s: dict[str, float] = {"validate": 900.0, "reconstruct": 5 * 3600.0}
    """Per-stage limit, checked between iterations; a stage over it fails the job."""

    device: str = "auto"
    """Worker device: ``auto`` (CUDA when available), ``cpu``, ``cuda``, ``cuda:1``..."""

    @property
    def db_url(self) -> str:
        """The effective database URL."""
        if self.database_url:
            return self.database_url
        return f"sqlite:///{self.storage_dir.resolve() / 'dcseg.db'}"

    def parsed_api_keys(self) -> dict[str, str]:
        """``{key: tenant}`` from :attr:`api_keys`."""
        text = self.api_keys.strip()
        if text.startswith("@"):
            text = Path(text[1:]).read_text(encoding="utf-8")
        pairs: dict[str, str] = {}
        for item in text.replace("\n", ",").split(","):
            item = item.strip()
            if not item or item.startswith("#"):
                continue
            tenant, sep, key = item.partition(":")
            if not sep or not tenant.strip() or not key.strip():
                raise ValueError("DCSEG_API_KEYS entries must look like tenant:key")
            pairs[key.strip()] = tenant.strip()
        return pairs


@lru_cache
def get_settings() -> Settings:
    """The process-wide settings (tests pass their own ``Settings`` to ``create_app``)."""
    return Settings()
