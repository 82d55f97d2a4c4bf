"""What the API and the workers agree on; standard library only (the API image imports it).

Job folder layout under the storage directory::

    uploads/<upload_id>/data/          the extracted upload (the archive root)
    jobs/<job_id>/output/<stage>/      one folder per finished stage (renamed into place)
    jobs/<job_id>/output/manifest.json the finished stages and their files (size, sha256)
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from dcseg.io.bundle import BUNDLE_LAYOUT, bundle_paths

TASK_RUN_JOB = "dcseg.run_job"
"""Celery task name of the pipeline; the API enqueues by this name (``send_task``)."""

DEFAULT_QUEUE = "gpu"
"""The queue the pipeline task is routed to (GPU stages)."""

MANIFEST = "manifest.json"
"""Name of the manifest of finished stages inside a job's output folder."""

TERMINAL = frozenset({"succeeded", "failed", "canceled"})
"""Job statuses that never change again."""

ACTIVE = frozenset({"queued", "running", "canceling"})
"""Job statuses that count against a tenant's running-job cap."""


@dataclass(frozen=True)
class UploadPaths:
    """Where an upload lives."""

    root: Path
    upload_id: str

    @property
    def folder(self) -> Path:
        return self.root / "uploads" / self.upload_id

    @property
    def data(self) -> Path:
        return self.folder / "data"


@dataclass(frozen=True)
class JobPaths:
    """Where a job's files live."""

    root: Path
    job_id: str

    @property
    def folder(self) -> Path:
        return self.root / "jobs" / self.job_id

    @property
    def output(self) -> Path:
        return self.folder / "output"

    @property
    def manifest(self) -> Path:
        return self.output / MANIFEST


def celery_config(
    *,
    queue: str = DEFAULT_QUEUE,
    visibility_timeout_s: int,
    soft_time_limit_s: int,
    time_limit_s: int,
) -> dict[str, Any]:
    """Celery settings shared by the API (sender) and the worker, as a plain dict.

    ``acks_late`` + ``reject_on_worker_lost``: a task is acknowledged only after it finished,
    so a killed worker's job is redelivered (``execute_job`` resumes after its last finished
    stage). Prefetch 1: a GPU worker never hoards jobs it cannot start.
    """
    return {
        "task_acks_late": True,
        "task_reject_on_worker_lost": True,
        "worker_prefetch_multiplier": 1,
        # a fresh child process per job hands all GPU memory back (prefork pool only)
        "worker_max_tasks_per_child": 1,
        "task_routes": {TASK_RUN_JOB: {"queue": queue}},
        "task_default_queue": queue,
        "task_soft_time_limit": soft_time_limit_s,
        "task_time_limit": time_limit_s,
        "task_ignore_result": True,
        "task_serializer": "json",
        "accept_content": ["json"],
        "broker_transport_options": {"visibility_timeout": visibility_timeout_s},
        "broker_connection_retry_on_startup": True,
        # Redis restarting under a worker: the running job goes on (its lease lives in the job
        # store, not in the broker) and the worker reconnects. Pinned because Celery 6 turns
        # this on (cancelling the job, whose message the restart may have lost anyway).
        "worker_cancel_long_running_tasks_on_connection_loss": False,
        "worker_hijack_root_logger": False,
        "worker_send_task_events": False,
    }


INPUT_LAYOUT = BUNDLE_LAYOUT
"""Optional inputs inside an upload (see :mod:`dcseg.io.bundle`)."""


def input_layout(root: Path) -> dict[str, Any]:
    """The keyword arguments of ``dcseg.inputs.RunInputs`` for an extracted upload."""
    return dict(bundle_paths(root))


def _tree_digest(paths: list[Path], root: Path) -> str:
    digest = hashlib.sha256()
    for path in sorted(paths):
        digest.update(path.relative_to(root).as_posix().encode() + b"\0")
        with path.open("rb") as handle:
            while chunk := handle.read(1 << 20):
                digest.update(chunk)
        digest.update(b"\0")
    return digest.hexdigest()


def input_digests(root: Path) -> dict[str, str]:
    """SHA-256 of each input of an extracted upload (capture files, each mask folder, the
    vocabulary, the ground truth). A derived job reuses a parent's stage only when the inputs
    that stage reads have the same digest."""
    layout = input_layout(root)
    files = [p for p in root.rglob("*") if p.is_file()]
    optional = {name: path for name, path in layout.items() if name != "capture" and path}
    digests: dict[str, str] = {}
    for name, path in optional.items():
        digests[name] = _tree_digest([f for f in files if f == path or path in f.parents], root)
    reserved = [root / "masks", root / "gt", *(root / c for c in INPUT_LAYOUT["vocabulary"])]
    capture = [f for f in files if not any(f == r or r in f.parents for r in reserved)]
    digests["capture"] = _tree_digest(capture, root)
    return digests
