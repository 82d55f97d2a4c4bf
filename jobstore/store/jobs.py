"""Jobs as the API sees them: created under the tenant's cap, read, listed, canceled, deleted."""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime

from sqlalchemy import delete, func, select
from sqlalchemy.orm import Session

from jobstore.contract import ACTIVE, TERMINAL
from jobstore.models import Event, Job, Tenant, WebhookAttempt, WebhookDelivery
from jobstore.store.events import EventsMixin


class TooManyJobs(Exception):
    """The tenant already has its cap of unfinished jobs (answered with 429)."""

    def __init__(self, active: int, limit: int) -> None:
        super().__init__(f"{active} unfinished jobs; the limit is {limit}")
        self.active = active
        self.limit = limit


class Conflict(Exception):
    """The job's state forbids the operation (answered with 409)."""

    def __init__(self, job: Job, detail: str) -> None:
        super().__init__(detail)
        self.job = job
        self.detail = detail


@dataclass(frozen=True)
class Cursor:
    """Position after the last job of a page (jobs are listed newest first)."""

    created_at: datetime
    job_id: str


class JobsMixin(EventsMixin):
    """The API side of a job's life (the worker side is :mod:`jobstore.store.leases`)."""

    def create_job(self, job: Job, *, max_active: int | None = None) -> Job:
        """Insert a queued job and its first event; ``TooManyJobs`` when the tenant already
        has ``max_active`` unfinished jobs.

        Count and insert share one transaction that holds the tenant's row lock (PostgreSQL;
        SQLite's ``BEGIN IMMEDIATE`` serialises all writers), so concurrent requests cannot
        both pass the check.
        """
        with self.session() as s:
            if max_active is not None:
                s.get(Tenant, job.tenant_id, with_for_update={"key_share": True})
                active = self._count_active(s, job.tenant_id)
                if active >= max_active:
                    raise TooManyJobs(active, max_active)
            s.add(job)
            s.flush()
            self._event(s, job, "status", {"status": job.status})
        return job

    def get_job(self, job_id: str, tenant: str | None = None) -> Job | None:
        """The job, or None when it does not exist or belongs to another tenant."""
        with self.session(write=False) as s:
            job = s.get(Job, job_id)
        if job is None or (tenant is not None and job.tenant_id != tenant):
            return None
        return job

    def list_jobs(
        self, tenant: str, *, status: str | None, after: Cursor | None, limit: int
    ) -> tuple[list[Job], bool]:
        """A page of the tenant's jobs, newest first, and whether more follow."""
        query = select(Job).where(Job.tenant_id == tenant)
        if status is not None:
            query = query.where(Job.status == status)
        if after is not None:
            query = query.where(
                (Job.created_at < after.created_at)
                | ((Job.created_at == after.created_at) & (Job.id < after.job_id))
            )
        query = query.order_by(Job.created_at.desc(), Job.id.desc()).limit(limit + 1)
        with self.session(write=False) as s:
            jobs = list(s.scalars(query))
        return jobs[:limit], len(jobs) > limit

    def count_active(self, tenant: str) -> int:
        with self.session(write=False) as s:
            return self._count_active(s, tenant)

    @staticmethod
    def _count_active(s: Session, tenant: str) -> int:
        query = select(func.count()).where(Job.tenant_id == tenant, Job.status.in_(ACTIVE))
        return int(s.scalar(query) or 0)

    def request_cancel(self, job_id: str, tenant: str) -> Job | None:
        """Cancel a queued job at once, or flag a running one; Conflict when terminal."""
        with self.session() as s:
            job = self._lock(s, job_id, tenant)
            if job is None:
                return None
            if job.status in TERMINAL:
                raise Conflict(job, f"job is already {job.status}")
            job.cancel_requested = True
            if job.status == "queued":
                self._finish(s, job, "canceled", None, "canceled before it started")
            elif job.status == "running":
                self._set(s, job, status="canceling", message="cancel requested")
        return job

    def delete_job(self, job_id: str, tenant: str) -> Job | None:
        """Delete a finished job's record, events and webhook deliveries; Conflict while it is
        unfinished."""
        with self.session() as s:
            job = self._lock(s, job_id, tenant)
            if job is None:
                return None
            if job.status not in TERMINAL:
                raise Conflict(job, f"job is {job.status}; cancel it and wait until it ends")
            for ev in s.scalars(select(Event).where(Event.job_id == job_id)):
                s.delete(ev)
            deliveries = select(WebhookDelivery.id).where(WebhookDelivery.job_id == job_id)
            s.execute(delete(WebhookAttempt).where(WebhookAttempt.delivery_id.in_(deliveries)))
            s.execute(delete(WebhookDelivery).where(WebhookDelivery.job_id == job_id))
            s.delete(job)
        return job
