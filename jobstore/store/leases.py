"""Jobs as the workers see them: a lease (claim, heartbeat, progress, finish) and the sweeps
that give the job of a dead worker to another one.

A running job is held by one worker id (``host:pid:thread``) whose heartbeat, read from the
database's clock, keeps the lease; a lease older than ``stale_after`` may be taken over. A job
claimed ``max_attempts`` times fails instead (its workers keep dying).
"""

from __future__ import annotations

from datetime import timedelta
from typing import Any, Literal

from sqlalchemy import select
from sqlalchemy.orm import Session

from jobstore.contract import TERMINAL
from jobstore.models import Job
from jobstore.store.events import EventsMixin

Lease = Literal["ok", "cancel", "lost"]
"""What a worker learns when it reports: go on, stop for a cancel, or stop (job taken over)."""


class LeasesMixin(EventsMixin):
    """The worker side of a job's life (the API side is :mod:`jobstore.store.jobs`)."""

    def claim_job(self, job_id: str, worker: str, stale_after: timedelta) -> Job | None:
        """Make ``worker`` the job's runner, or return None if it must not run it.

        A queued job is claimed; a running job only when its heartbeat is older than
        ``stale_after`` (its worker died and the task was redelivered); a job with a cancel
        request ends ``canceled`` here, and a job already claimed ``max_attempts`` times ends
        ``failed`` (its workers keep dying).
        """
        with self.session() as s:
            job = self._lock(s, job_id, None)
            if job is None or job.status in TERMINAL:
                return None
            now = self._now(s)
            if job.cancel_requested:
                self._finish(s, job, "canceled", None, "canceled before it resumed")
                return None
            beat = job.heartbeat_at
            if job.status == "running" and beat is not None and now - beat < stale_after:
                return None
            if self._fail_if_exhausted(s, job):
                return None
            resumed = job.status == "running"
            job.attempts += 1
            job.started_at = job.started_at or now
            self._set(
                s,
                job,
                status="running",
                worker=worker,
                heartbeat_at=now,
                message="resumed after a lost worker" if resumed else "started",
            )
        return job

    def release_attempts_of(self, worker: str) -> list[str]:
        """Runs of ``worker``, or of any worker id under it (``host:pid`` covers every
        ``host:pid:thread``), stopped for a shutdown: each job still held by one of them
        (running or canceling) gets its attempt back and is given up at once (lease expired,
        no runner), so it is released once only. Returns the released jobs' ids."""
        owners = (Job.worker == worker) | Job.worker.startswith(f"{worker}:", autoescape=True)
        query = (
            select(Job)
            .where(Job.status.in_(("running", "canceling")), owners)
            .order_by(Job.id)
            .with_for_update()
        )
        with self.session() as s:
            jobs = list(s.scalars(query))
            stale = self._now(s) - timedelta(days=1)  # stale for any heartbeat_s
            for job in jobs:
                job.attempts = max(0, job.attempts - 1)
                job.heartbeat_at, job.worker = stale, None
            return [job.id for job in jobs]

    def next_queued(self) -> str | None:
        """The oldest queued job's id (the embedded worker's queue)."""
        query = select(Job.id).where(Job.status == "queued").order_by(Job.created_at).limit(1)
        with self.session(write=False) as s:
            return s.scalar(query)

    def heartbeat(self, job_id: str, worker: str) -> Lease:
        """Refresh ``worker``'s lease on the job; says whether to go on, cancel or stop."""
        with self.session() as s:
            job = self._owned(s, job_id, worker)
            if job is None:
                return "lost"
            job.heartbeat_at = self._now(s)
            return "cancel" if job.cancel_requested else "ok"

    def report_progress(
        self,
        job_id: str,
        worker: str,
        stage: tuple[str, int, int],
        fraction: float,
        message: str,
    ) -> Lease:
        """Record progress (``stage`` = name, index, count) and emit a ``progress`` event."""
        name, index, count = stage
        with self.session() as s:
            job = self._owned(s, job_id, worker)
            if job is None:
                return "lost"
            job.stage, job.stage_index, job.stage_count = name, index, count
            job.progress = max(0.0, min(1.0, fraction))
            job.message = message
            job.heartbeat_at = job.updated_at = self._now(s)
            data = {"stage": name, "stage_index": index, "stage_count": count}
            self._event(s, job, "progress", data | {"fraction": job.progress, "message": message})
            return "cancel" if job.cancel_requested else "ok"

    def log(self, job_id: str, message: str, **data: Any) -> None:
        with self.session() as s:
            job = self._lock(s, job_id, None)
            if job is not None:
                self._event(s, job, "log", {"message": message, **data})

    def finish_job(
        self,
        job_id: str,
        status: str,
        error: dict[str, Any] | None = None,
        message: str = "",
        *,
        worker: str | None = None,
    ) -> str | None:
        """Move a job to a terminal status and emit the ``completed`` event; returns the
        status recorded, or None when nothing changed.

        A job whose cancel was acknowledged (``canceling``) ends ``canceled`` whatever its run
        reports (a failure's ``error`` is kept). With ``worker``, only while that worker still
        holds the job (a worker whose lease was taken over must not overwrite the new run's
        outcome).
        """
        with self.session() as s:
            job = self._owned(s, job_id, worker) if worker else self._lock(s, job_id, None)
            if job is None or job.status in TERMINAL:
                return None
            if job.status == "canceling" and status != "canceled":
                message = f"canceled (cancel requested; the run had ended {status})"
                status = "canceled"
            self._finish(s, job, status, error, message)
            return status

    def requeue_running(self) -> list[str]:
        """Startup sweep of the embedded mode: running jobs go back to the queue (jobs at
        ``max_attempts`` fail instead); returns the requeued ones."""
        ids: list[str] = []
        with self.session() as s:
            query = select(Job).where(Job.status.in_(("running", "canceling"))).with_for_update()
            for job in s.scalars(query):
                if job.cancel_requested:
                    self._finish(s, job, "canceled", None, "canceled while the service was down")
                elif not self._fail_if_exhausted(s, job):
                    ids.append(job.id)
                    self._set(s, job, status="queued", worker=None, message="requeued at startup")
        return ids

    def requeue_stale(self, stale_after: timedelta) -> list[str]:
        """Running jobs whose worker stopped heartbeating go back to ``queued`` (jobs at
        ``max_attempts`` fail instead); returns the requeued ones.

        Safe with several API replicas: each job row is locked, so only one requeues it.
        """
        ids: list[str] = []
        with self.session() as s:
            cutoff = self._now(s) - stale_after
            query = (
                select(Job)
                .where(Job.status.in_(("running", "canceling")), Job.heartbeat_at <= cutoff)
                .with_for_update(skip_locked=True)
            )
            for job in s.scalars(query):
                if job.cancel_requested:
                    self._finish(s, job, "canceled", None, "canceled; its worker was lost")
                elif not self._fail_if_exhausted(s, job):
                    ids.append(job.id)
                    self._set(s, job, status="queued", worker=None, message="worker lost; requeued")
        return ids

    def unfinished(self, stale_after: timedelta) -> list[str]:
        """Queued jobs and running jobs whose heartbeat is stale (the Celery-mode sweep)."""
        with self.session(write=False) as s:
            cutoff = self._now(s) - stale_after
            query = select(Job.id).where(
                (Job.status == "queued")
                | (
                    (Job.status == "running")
                    & ((Job.heartbeat_at <= cutoff) | Job.heartbeat_at.is_(None))
                )
            )
            return list(s.scalars(query.order_by(Job.created_at)))

    def _owned(self, s: Session, job_id: str, worker: str) -> Job | None:
        """The job if ``worker`` holds it (running or canceling), else None."""
        job = self._lock(s, job_id, None)
        if job is None or job.worker != worker or job.status not in ("running", "canceling"):
            return None
        return job

    def _fail_if_exhausted(self, s: Session, job: Job) -> bool:
        """Fail the job if it was claimed ``max_attempts`` times already; returns whether."""
        if job.attempts < self.max_attempts:
            return False
        detail = (
            f"the job's worker died {job.attempts} times (OOM kill or crash?); giving up after "
            f"{self.max_attempts} attempts (DCSEG_MAX_ATTEMPTS). Retry with a smaller "
            "capture or preset, or on a worker with more memory"
        )
        error = {"type": "too-many-attempts", "detail": detail, "attempts": job.attempts}
        self._finish(s, job, "failed", error, f"failed after {job.attempts} attempts")
        return True
