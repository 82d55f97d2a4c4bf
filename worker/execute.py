"""``execute_job``: run a job's stages one by one, resumably, with progress and cancellation.

No Celery here: the Celery task and the embedded worker both call :func:`execute_job`.

Each stage writes into ``<workspace output>/.tmp-<stage>/``; when it returns, the workspace
commits it (:mod:`worker.workspace`: renamed to ``output/<stage>/`` and appended to
``output/manifest.json`` in the shared folder, or uploaded and its manifest object written
last in object storage). A redelivered job therefore skips every stage in the manifest and
redoes at most the stage it was in; a half-written stage is never listed as an artifact.
"""

from __future__ import annotations

import functools
import hashlib
import json
import logging
import os
import shutil
import socket
import threading
import time
import uuid
from collections.abc import Callable, Sequence
from datetime import UTC, datetime, timedelta
from pathlib import Path
from types import TracebackType
from typing import Any

from jobstore.blobstore import Storage, make_storage
from jobstore.settings import Settings
from jobstore.store import Lease, Store
from worker.stage import Stage, StageContext, StageOutcome
from worker.watchdog import StageTimeout, StageWatchdog, stage_time_limit
from worker.workspace import (
    CommitRefused,
    ScratchFull,
    Workspace,
    open_workspace,
)
from worker.workspace import read_manifest as read_manifest

logger = logging.getLogger(__name__)

MANIFEST_VERSION = 1
PROGRESS_EVERY_S = 0.5
"""Progress is written to the store at most this often (the last report always is)."""


class Canceled(Exception):
    """The job's cancel flag was seen."""


class Interrupted(Exception):
    """The worker is shutting down; the job stays ``running`` and is resumed later."""


class LeaseLost(Exception):
    """Another worker took the job over (this one was presumed dead); stop without writing."""


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as handle:
        while chunk := handle.read(1 << 20):
            digest.update(chunk)
    return digest.hexdigest()


def _key_hash(key: dict[str, Any]) -> str:
    return hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()


class Heartbeat:
    """A thread refreshing the job's lease and noticing cancel requests while a stage runs."""

    def __init__(self, store: Store, job_id: str, worker: str, every_s: float) -> None:
        self.store, self.job_id, self.worker, self.every_s = store, job_id, worker, every_s
        self.state: Lease = "ok"
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name=f"heartbeat-{job_id}", daemon=True)

    def _loop(self) -> None:
        while not self._stop.wait(self.every_s):
            try:
                self.update(self.store.heartbeat(self.job_id, self.worker))
            except Exception:  # keep beating through database hiccups
                logger.warning("heartbeat of job %s failed", self.job_id, exc_info=True)

    def update(self, state: Lease) -> None:
        if self.state != "lost":
            self.state = state

    def __enter__(self) -> Heartbeat:
        self._thread.start()
        return self

    def __exit__(
        self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self._stop.set()
        self._thread.join()


class _Runner:
    """Runs the stages of one claimed job."""

    def __init__(
        self,
        store: Store,
        settings: Settings,
        job_id: str,
        workspace: Workspace,
        stages: Sequence[Stage],
        heartbeat: Heartbeat,
        interrupt: Callable[[], bool],
        watchdog: StageWatchdog | None = None,
    ) -> None:
        self.store, self.settings, self.job_id = store, settings, job_id
        self.workspace = workspace
        self.stages, self.heartbeat, self.interrupt = stages, heartbeat, interrupt
        self.watchdog = watchdog
        self._last_report = 0.0
        self._deadline = float("inf")
        self._timeout: StageTimeout | None = None

    def check(self, *, interrupt: bool = True) -> None:
        """Raise if the job must stop: cancel flag, worker shutdown (unless not ``interrupt``)
        or stage time limit."""
        if self.heartbeat.state == "lost":
            raise LeaseLost()
        if self.heartbeat.state == "cancel":
            raise Canceled()
        if interrupt and self.interrupt():
            raise Interrupted()
        if self.watchdog is not None and self.watchdog.fired is not None:
            raise self.watchdog.fired
        if self._timeout is not None and time.monotonic() > self._deadline:
            raise self._timeout

    def _start_clock(self, stage: str) -> None:
        """Start the stage's time limit (checked at progress reports and by the watchdog)."""
        limit = stage_time_limit(self.settings, stage)
        self._timeout = StageTimeout(stage, limit)
        self._deadline = time.monotonic() + limit
        if self.watchdog is not None:
            self.watchdog.arm(stage, limit)

    def _stop_clock(self) -> None:
        self._timeout, self._deadline = None, float("inf")
        if self.watchdog is not None:
            self.watchdog.disarm()

    def report(self, name: str, index: int, fraction: float, message: str, force: bool) -> None:
        self.check()
        now = time.monotonic()
        if not force and now - self._last_report < PROGRESS_EVERY_S and fraction < 1.0:
            return
        self._last_report = now
        overall = (index + max(0.0, min(1.0, fraction))) / len(self.stages)
        job_id = self.job_id
        stage = (name, index, len(self.stages))
        worker = self.heartbeat.worker
        self.heartbeat.update(self.store.report_progress(job_id, worker, stage, overall, message))
        self.check()

    def _progress(self, index: int, stage: str, fraction: float, message: str) -> None:
        self.report(self.stages[index].name, index, fraction, message, False)

    def _log(self, name: str, message: str) -> None:
        self.store.log(self.job_id, message, stage=name)

    def run(self, input_root: Path, config: dict[str, Any], parent_id: str | None) -> None:
        workspace = self.workspace
        manifest = workspace.manifest()
        finished = {s["name"] for s in manifest["stages"]}
        parent_stages = {s["name"]: s for s in workspace.parent_manifest()["stages"]}
        job_id = self.job_id
        for index, stage in enumerate(self.stages):
            if stage.name in finished:
                self.store.log(job_id, f"{stage.name}: already finished", stage=stage.name)
                continue
            self.check()
            self._start_clock(stage.name)
            self.report(stage.name, index, 0.0, f"{stage.name}: started", force=True)
            key = _key_hash(stage.key(config))
            tmp = workspace.output / f".tmp-{stage.name}-{uuid.uuid4().hex[:8]}"
            tmp.mkdir()
            entry = parent_stages.get(stage.name)
            outcome = _reuse_parent_stage(workspace, entry, key, tmp, parent_id)
            if outcome is None:
                ctx = StageContext(
                    job_id=job_id,
                    input_root=input_root,
                    config=config,
                    settings=self.settings,
                    progress=functools.partial(self._progress, index),
                    log=functools.partial(self._log, stage.name),
                    output_root=workspace.output,
                )
                outcome = stage.run(ctx, tmp)
            self._stop_clock()
            # a worker that lost its lease or was canceled must not commit; a shutdown must
            # not discard a finished stage: it is committed, the next report interrupts
            self.check(interrupt=False)
            workspace.commit(_entry(stage.name, index, key, tmp, outcome), tmp, manifest)
            message = outcome.message or f"{stage.name}: {outcome.status}"
            self.report(stage.name, index, 1.0, message, force=True)


def _entry(name: str, index: int, key: str, tmp: Path, outcome: StageOutcome) -> dict[str, Any]:
    """The manifest entry of stage ``name`` whose files are in ``tmp``."""
    files = {
        f"{name}/{path.relative_to(tmp).as_posix()}": {
            "size": path.stat().st_size,
            "sha256": _sha256(path),
        }
        for path in sorted(tmp.rglob("*"))
        if path.is_file()
    }
    return {
        "name": name,
        "index": index,
        "key": key,
        "status": outcome.status,
        "message": outcome.message,
        "details": outcome.details,
        "files": files,
        "finished_at": datetime.now(UTC).isoformat(),
    }


def _reuse_parent_stage(
    workspace: Workspace, entry: dict[str, Any] | None, key: str, tmp: Path, parent_id: str | None
) -> StageOutcome | None:
    """Put the parent's finished stage into ``tmp`` when its key matches, or return None to
    run the stage. Also None when a file of the parent's manifest entry is gone or changed
    (the parent was deleted meanwhile): the stage is redone rather than recorded empty."""
    if entry is None or entry.get("key") != key or entry["status"] != "done":
        return None
    try:
        workspace.reuse(entry, tmp)
    except (OSError, ValueError) as error:
        logger.warning(
            "stage %s of parent job %s cannot be reused (%s); running it",
            entry["name"],
            parent_id,
            error,
        )
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir()
        return None
    return StageOutcome("done", f"reused from job {parent_id}", {"reused": True})


def worker_id_prefix(pid: int) -> str:
    """``host:pid``: what the worker ids of process ``pid`` on this host start with."""
    return f"{socket.gethostname()}:{pid}"


def default_worker_id() -> str:
    """``host:pid:thread`` (see :func:`worker_id_prefix`)."""
    return f"{worker_id_prefix(os.getpid())}:{threading.get_ident()}"


def error_body(
    error: BaseException, job_id: str = "-", input_root: Path | None = None
) -> dict[str, Any]:
    """The job's ``error`` as clients see it, and the server-side log line of the failure.

    Input problems keep their file (relative to the upload) and reason, time limits name the
    stage, its limit and the setting. Anything else may carry storage paths, broker or
    database URLs in its text: clients get a generic message with an ``error_id``, and the
    full exception and traceback are logged under that id.
    """
    from dcseg.errors import InputError

    if isinstance(error, InputError):
        logger.warning("job %s: invalid input: %s", job_id, error)
        errors = [
            {"path": _relative(p.path, input_root), "reason": _relative(p.reason, input_root)}
            for p in error.problems
        ]
        detail = "; ".join(f"{e['path']}: {e['reason']}" for e in errors)
        return {"type": "invalid-input", "detail": detail, "errors": errors}
    if isinstance(error, ScratchFull):
        logger.warning("job %s: %s", job_id, error)
        return {"type": "scratch-full", "detail": str(error)}
    if isinstance(error, StageTimeout):
        logger.warning("job %s: %s", job_id, error)
        return {"type": "timeout", "detail": str(error)}
    if type(error).__name__ == "SoftTimeLimitExceeded":  # Celery's, without importing Celery
        logger.warning("job %s: ran past DCSEG_TASK_SOFT_TIME_LIMIT_S", job_id)
        detail = "the job ran past its time limit (setting DCSEG_TASK_SOFT_TIME_LIMIT_S)"
        return {"type": "timeout", "detail": detail}
    error_id = uuid.uuid4().hex[:12]
    logger.error("job %s failed, error id %s", job_id, error_id, exc_info=error)
    detail = f"internal error {error_id}; the operator can find it in the worker log"
    return {"type": "internal", "detail": detail, "error_id": error_id}


def _relative(text: str, root: Path | None) -> str:
    """``text`` with the upload's absolute location removed (paths relative to the upload)."""
    if root is None:
        return text
    for prefix in {str(root), str(root.resolve())}:
        text = text.replace(prefix + os.sep, "").replace(prefix, ".")
    return text


def execute_job(
    job_id: str,
    store: Store,
    settings: Settings,
    *,
    stages: Sequence[Stage] | None = None,
    worker_id: str | None = None,
    interrupt: Callable[[], bool] | None = None,
    kill: Callable[[], None] | None = None,
    storage: Storage | None = None,
) -> str:
    """Claim and run a job; returns its final status, ``skipped``, ``interrupted`` or ``lost``.

    Args:
        job_id: the job to run.
        store: the job store (progress, events, cancel flag, lease).
        settings: deployment settings (storage folder, time limits, device).
        stages: the pipeline stages (default: :func:`worker.stages.default_stages`).
        worker_id: who runs it (default: host, pid and thread).
        interrupt: polled between iterations; True stops the job without finishing it (it is
            resumed when claimed again).
        kill: ends this process; called after the job is failed when a stage runs
            ``stage_kill_grace_s`` past its limit without a progress report (None: the stuck
            stage is abandoned, in a thread that cannot be stopped).
        storage: where uploads and outputs live (default: from the settings).
    """
    worker = worker_id or default_worker_id()
    job = store.claim_job(job_id, worker, timedelta(seconds=3 * settings.heartbeat_s))
    if job is None:
        logger.info("job %s not claimed (finished, canceled or owned by a live worker)", job_id)
        return "skipped"
    if stages is None:
        from worker.stages import default_stages

        stages = default_stages()
    upload = store.get_upload(job.upload_id, job.tenant_id)
    storage = storage or make_storage(settings)
    overrun = _overrun(store, job_id, worker, kill)
    input_root: Path | None = None
    with (
        Heartbeat(store, job_id, worker, settings.heartbeat_s) as heartbeat,
        StageWatchdog(settings.stage_kill_grace_s, overrun) as watchdog,
    ):

        def lease_check() -> None:
            """Before writing to shared storage: is the lease still this worker's?"""
            heartbeat.update(store.heartbeat(job_id, worker))
            if heartbeat.state == "lost":
                raise LeaseLost()

        workspace = open_workspace(
            storage, settings, job.tenant_id, job_id, job.parent_job_id, lease_check
        )
        runner = _Runner(
            store,
            settings,
            job_id,
            workspace,
            stages,
            heartbeat,
            interrupt or (lambda: False),
            watchdog,
        )
        try:
            if upload is None:
                raise FileNotFoundError(f"upload {job.upload_id} is gone")
            digests = upload.summary.get("digests") or {"upload": upload.id}
            config = {**job.config, "inputs": digests}
            input_root = workspace.inputs(upload)
            runner.run(input_root, config, job.parent_job_id)
        except Canceled:
            return _finish(store, job_id, worker, "canceled", None)
        except Interrupted:
            return _interrupted(store, job_id, worker, heartbeat)
        except (LeaseLost, CommitRefused):
            if watchdog.fired is not None:  # the watchdog failed the job; its stage returned
                return "failed"
            logger.warning("job %s was taken over by another worker; stopping", job_id)
            return "lost"
        except Exception as error:
            if watchdog.fired is not None:
                return "failed"
            return _finish(store, job_id, worker, "failed", error_body(error, job_id, input_root))
        finally:
            workspace.close()
    return _finish(store, job_id, worker, "succeeded", None)


def _interrupted(store: Store, job_id: str, worker: str, heartbeat: Heartbeat) -> str:
    """Give the job up unfinished: stop the heartbeat, then, in one write, give its attempt
    back (``max_attempts`` counts crashes, not shutdowns), expire the lease (the next delivery
    or the recovery sweep resumes it after its last finished stage at once) and drop this
    worker as its runner (so the embedded worker's parent does not give the attempt back a
    second time, see :meth:`Store.release_attempts_of`)."""
    heartbeat.__exit__(None, None, None)  # no beat may refresh the lease after this
    try:
        store.release_attempts_of(worker)
    except Exception:  # it then counts one attempt more and waits for the stale-lease sweep
        logger.warning("job %s: could not give up its lease", job_id, exc_info=True)
    logger.info("job %s interrupted by shutdown; it resumes on the next claim", job_id)
    return "interrupted"


def _overrun(
    store: Store, job_id: str, worker: str, kill: Callable[[], None] | None
) -> Callable[[StageTimeout], None]:
    """What the watchdog does with a stage stuck past its limit: fail the job, then kill the
    process if allowed (the stage may be stuck in native code, beyond any exception)."""

    def stop(timeout: StageTimeout) -> None:
        logger.error("job %s: %s and reported no progress; stopping it", job_id, timeout)
        _finish(store, job_id, worker, "failed", error_body(timeout, job_id))
        if kill is not None:
            logger.error("killing worker process %d, stuck in %s", os.getpid(), timeout.stage)
            kill()

    return stop


def _finish(
    store: Store, job_id: str, worker: str, status: str, error: dict[str, Any] | None
) -> str:
    recorded = store.finish_job(job_id, status, error, message=status, worker=worker)
    if recorded is not None:
        return recorded  # "canceled" when a cancel was acknowledged meanwhile
    logger.warning("job %s: not recorded as %s (taken over by another worker)", job_id, status)
    return "lost"
