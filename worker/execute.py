"""``execute_job``: run a job's stages one by one, resumably, with progress and cancellation.

No Celery here: the Celery task and the embedded worker both call :func:`execute_job`.

Each stage writes into ``output/.tmp-<stage>/``; when it returns, the folder is renamed to
``output/<stage>/`` and the stage is appended to ``output/manifest.json`` (written to a temp
name, then renamed). A redelivered job therefore skips every stage in the manifest and redoes
at most the stage it was in; a half-written stage folder is never listed as an artifact.
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
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from pathlib import Path
from types import TracebackType
from typing import Any, Literal, Protocol

from service.settings import Settings
from service.store import Lease, Store
from worker.contract import MANIFEST, JobPaths, UploadPaths

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


class StageTimeout(Exception):
    """A stage ran past its time limit."""


@dataclass(frozen=True)
class StageOutcome:
    """What a stage reports when it returns."""

    status: Literal["done", "skipped"] = "done"
    message: str = ""
    details: dict[str, Any] = field(default_factory=dict)


@dataclass
class StageContext:
    """What a stage may use: its inputs, the job's config, and the progress callback."""

    job_id: str
    input_root: Path
    config: dict[str, Any]
    settings: Settings
    progress: Callable[[float, str], None]
    """``progress(fraction_of_stage, message)``; raises to stop the stage (cancel, timeout)."""
    log: Callable[[str], None]
    output_root: Path | None = None
    """The job's output folder; finished stages' files are under ``output_root/<stage>/``."""


class Stage(Protocol):
    """One pipeline stage: writes its files into ``out`` and returns an outcome."""

    name: str

    def key(self, config: dict[str, Any]) -> dict[str, Any]:
        """The parameters the stage's output depends on (a derived job reuses the parent's
        output when they are equal)."""
        ...

    def run(self, ctx: StageContext, out: Path) -> StageOutcome: ...


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as handle:
        while chunk := handle.read(1 << 20):
            digest.update(chunk)
    return digest.hexdigest()


def _key_hash(key: dict[str, Any]) -> str:
    return hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()


def read_manifest(paths: JobPaths) -> dict[str, Any]:
    try:
        data: dict[str, Any] = json.loads(paths.manifest.read_text(encoding="utf-8"))
        return data
    except FileNotFoundError:
        return {"version": MANIFEST_VERSION, "job_id": paths.job_id, "stages": []}


def write_manifest(paths: JobPaths, manifest: dict[str, Any]) -> None:
    tmp = paths.output / f".{MANIFEST}.tmp"
    tmp.write_text(json.dumps(manifest, indent=2, sort_keys=True), encoding="utf-8")
    os.replace(tmp, paths.manifest)


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
        paths: JobPaths,
        stages: Sequence[Stage],
        heartbeat: Heartbeat,
        interrupt: Callable[[], bool],
    ) -> None:
        self.store, self.settings, self.paths = store, settings, paths
        self.stages, self.heartbeat, self.interrupt = stages, heartbeat, interrupt
        self._last_report = 0.0
        self._deadline = float("inf")
        self._stage_limit = 0.0

    def check(self) -> None:
        """Raise if the job must stop: cancel flag, worker shutdown or stage time limit."""
        if self.heartbeat.state == "lost":
            raise LeaseLost()
        if self.heartbeat.state == "cancel":
            raise Canceled()
        if self.interrupt():
            raise Interrupted()
        if time.monotonic() > self._deadline:
            raise StageTimeout(f"stage ran longer than its limit of {self._stage_limit:g} s")

    def report(self, name: str, index: int, fraction: float, message: str, force: bool) -> None:
        self.check()
        now = time.monotonic()
        if not force and now - self._last_report < PROGRESS_EVERY_S and fraction < 1.0:
            return
        self._last_report = now
        overall = (index + max(0.0, min(1.0, fraction))) / len(self.stages)
        job_id = self.paths.job_id
        stage = (name, index, len(self.stages))
        worker = self.heartbeat.worker
        self.heartbeat.update(self.store.report_progress(job_id, worker, stage, overall, message))
        self.check()

    def _progress(self, name: str, index: int, fraction: float, message: str) -> None:
        self.report(name, index, fraction, message, False)

    def _log(self, name: str, message: str) -> None:
        self.store.log(self.paths.job_id, message, stage=name)

    def run(self, input_root: Path, config: dict[str, Any], parent: JobPaths | None) -> None:
        self.paths.output.mkdir(parents=True, exist_ok=True)
        for stale in self.paths.output.glob(".tmp-*"):
            shutil.rmtree(stale, ignore_errors=True)
        manifest = read_manifest(self.paths)
        finished = {s["name"] for s in manifest["stages"]}
        parent_stages = {s["name"]: s for s in read_manifest(parent)["stages"]} if parent else {}
        job_id = self.paths.job_id
        for index, stage in enumerate(self.stages):
            if stage.name in finished:
                self.store.log(job_id, f"{stage.name}: already finished", stage=stage.name)
                continue
            self.check()
            self._stage_limit = self.settings.stage_time_limit_s.get(stage.name, float("inf"))
            self._deadline = time.monotonic() + self._stage_limit
            self.report(stage.name, index, 0.0, f"{stage.name}: started", force=True)
            key = _key_hash(stage.key(config))
            tmp = self.paths.output / f".tmp-{stage.name}-{uuid.uuid4().hex[:8]}"
            tmp.mkdir()
            outcome = _reuse_parent_stage(parent, parent_stages.get(stage.name), key, tmp)
            if outcome is None:
                ctx = StageContext(
                    job_id=job_id,
                    input_root=input_root,
                    config=config,
                    settings=self.settings,
                    progress=functools.partial(self._progress, stage.name, index),
                    log=functools.partial(self._log, stage.name),
                    output_root=self.paths.output,
                )
                outcome = stage.run(ctx, tmp)
            self._deadline = float("inf")
            self.check()  # a worker that lost its lease or was canceled must not commit
            manifest["stages"].append(self._commit(stage.name, index, key, tmp, outcome))
            write_manifest(self.paths, manifest)
            message = outcome.message or f"{stage.name}: {outcome.status}"
            self.report(stage.name, index, 1.0, message, force=True)

    def _commit(
        self, name: str, index: int, key: str, tmp: Path, outcome: StageOutcome
    ) -> dict[str, Any]:
        files = {
            f"{name}/{path.relative_to(tmp).as_posix()}": {
                "size": path.stat().st_size,
                "sha256": _sha256(path),
            }
            for path in sorted(tmp.rglob("*"))
            if path.is_file()
        }
        final = self.paths.output / name
        if final.exists():  # left by a crash between rename and manifest write
            shutil.rmtree(final)
        os.rename(tmp, final)
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
    parent: JobPaths | None, entry: dict[str, Any] | None, key: str, tmp: Path
) -> StageOutcome | None:
    """Link the parent's finished stage into ``tmp`` when its key matches, or return None to
    run the stage. Also None when a file of the parent's manifest entry is gone or changed
    (the parent was deleted meanwhile): the stage is redone rather than recorded empty."""
    if parent is None or entry is None or entry.get("key") != key or entry["status"] != "done":
        return None
    try:
        _link_files(parent.output, entry["files"], entry["name"], tmp)
    except (OSError, ValueError) as error:
        logger.warning(
            "stage %s of parent job %s cannot be reused (%s); running it",
            entry["name"],
            parent.job_id,
            error,
        )
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir()
        return None
    return StageOutcome("done", f"reused from job {parent.job_id}", {"reused": True})


def _link_files(source: Path, files: dict[str, Any], name: str, dest: Path) -> None:
    """Hard-link (or copy) each manifest file ``<name>/<path>`` of ``source`` to
    ``dest/<path>``; ValueError when a linked file's size differs from the manifest's."""
    for entry, meta in files.items():
        relative = Path(entry).relative_to(name)
        target = dest / relative
        target.parent.mkdir(parents=True, exist_ok=True)
        try:
            os.link(source / entry, target)
        except OSError:  # another filesystem, say (a vanished file fails the copy too)
            shutil.copy2(source / entry, target)
        if target.stat().st_size != meta["size"]:
            raise ValueError(f"{entry} is {target.stat().st_size} bytes, not {meta['size']}")


def default_worker_id() -> str:
    return f"{socket.gethostname()}:{os.getpid()}:{threading.get_ident()}"


def error_body(error: BaseException) -> dict[str, Any]:
    """The job's ``error`` for an exception (input problems keep their file and reason)."""
    from dcseg.errors import InputError

    if isinstance(error, InputError):
        errors = [{"path": p.path, "reason": p.reason} for p in error.problems]
        return {"type": "invalid-input", "detail": str(error), "errors": errors}
    if isinstance(error, StageTimeout):
        return {"type": "timeout", "detail": str(error)}
    if type(error).__name__ == "SoftTimeLimitExceeded":  # Celery's, without importing Celery
        return {"type": "timeout", "detail": "the job ran past its time limit"}
    return {"type": "internal", "detail": f"{type(error).__name__}: {error}"}


def execute_job(
    job_id: str,
    store: Store,
    settings: Settings,
    *,
    stages: Sequence[Stage] | None = None,
    worker_id: str | None = None,
    interrupt: Callable[[], bool] | None = None,
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
    paths = JobPaths(settings.storage_dir, job_id)
    parent = JobPaths(settings.storage_dir, job.parent_job_id) if job.parent_job_id else None
    with Heartbeat(store, job_id, worker, settings.heartbeat_s) as heartbeat:
        runner = _Runner(store, settings, paths, stages, heartbeat, interrupt or (lambda: False))
        try:
            if upload is None:
                raise FileNotFoundError(f"upload {job.upload_id} is gone")
            data = UploadPaths(settings.storage_dir, upload.id).data
            digests = upload.summary.get("digests") or {"upload": upload.id}
            config = {**job.config, "inputs": digests}
            runner.run(data / str(upload.summary.get("root", ".")), config, parent)
        except Canceled:
            return _finish(store, job_id, worker, "canceled", None)
        except Interrupted:
            logger.info("job %s interrupted by shutdown; it resumes on the next claim", job_id)
            _not_a_crash(store, job_id, worker)
            return "interrupted"
        except LeaseLost:
            logger.warning("job %s was taken over by another worker; stopping", job_id)
            return "lost"
        except Exception as error:
            logger.exception("job %s failed", job_id)
            return _finish(store, job_id, worker, "failed", error_body(error))
    return _finish(store, job_id, worker, "succeeded", None)


def _not_a_crash(store: Store, job_id: str, worker: str) -> None:
    """A run stopped by a shutdown gives its attempt back (``max_attempts`` counts crashes)."""
    try:
        store.release_attempt(job_id, worker)
    except Exception:  # the job then counts one attempt more; never block the shutdown
        logger.warning("job %s: could not release its attempt", job_id, exc_info=True)


def _finish(
    store: Store, job_id: str, worker: str, status: str, error: dict[str, Any] | None
) -> str:
    recorded = store.finish_job(job_id, status, error, message=status, worker=worker)
    if recorded is not None:
        return recorded  # "canceled" when a cancel was acknowledged meanwhile
    logger.warning("job %s: not recorded as %s (taken over by another worker)", job_id, status)
    return "lost"
