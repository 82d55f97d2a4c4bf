"""Exports of a finished job (``dcseg.export``), made on demand and cached in the job's folder.

An export is made once per (selection, format): the whole scene or one instance. The first
request starts it on a thread of :class:`Exporter`, which runs ``export_run`` in a child
process of its own (spawned: the API process never imports the exporters' dependencies, an
export cannot block the event loop, and one past ``DCSEG_EXPORT_TIME_LIMIT_S`` is killed).
The child writes into a temporary folder; its files are hashed, checked against
``DCSEG_MAX_EXPORT_BYTES`` and renamed into place with a manifest, so a reader sees a whole
export or none. A failure is cached the same way (``error.json``) for the limits it met.

Layout inside ``jobs/<job_id>/``::

    exports/<scene|instance-K>/<format>/manifest.json   {format, instance, files: [...]}
    exports/<scene|instance-K>/<format>/files/...       the exported files
    exports/<scene|instance-K>/<format>/error.json      a failed export {type, detail, limits}
"""

from __future__ import annotations

import hashlib
import json
import logging
import multiprocessing
import os
import shutil
import threading
import time
import uuid
from collections.abc import Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any, get_args

from service.export_child import RUN, run_exporter
from service.schemas import ExportFormat
from service.settings import Settings
from worker.contract import JobPaths

logger = logging.getLogger(__name__)

FORMATS: tuple[str, ...] = get_args(ExportFormat)
"""Export formats the service offers (those of ``dcseg.export``)."""
EXPORTER = "dcseg.export:export_run"
"""``module:function`` the child process calls: ``(run, out, fmt, *, instances) -> paths``."""


def run_folder(paths: JobPaths) -> Path:
    """The finished run an export reads: the job's segment stage folder."""
    return paths.output / RUN


@dataclass(frozen=True)
class Selection:
    """What an export holds: the whole scene (``instance`` None) or one object."""

    fmt: str
    instance: int | None = None

    @property
    def folder_name(self) -> str:
        return "scene" if self.instance is None else f"instance-{self.instance}"

    def folder(self, job_folder: Path) -> Path:
        return job_folder / "exports" / self.folder_name / self.fmt


@dataclass(frozen=True)
class ExportFile:
    name: str
    """Path relative to the export's ``files/`` folder."""
    path: Path
    size: int
    sha256: str


@dataclass(frozen=True)
class Done:
    files: list[ExportFile]


@dataclass(frozen=True)
class Failed:
    slug: str
    """``export-failed`` (the run cannot be exported so), ``export-too-large``,
    ``export-timed-out`` or ``export-error`` (an internal error, with ``error_id``)."""
    detail: str
    errors: list[dict[str, str]]


def limits_of(settings: Settings) -> dict[str, float]:
    """The limits a cached failure was met under (a failure under other limits is retried)."""
    return {"time_s": settings.export_time_limit_s, "bytes": settings.max_export_bytes}


def read_cached(folder: Path, settings: Settings) -> Done | Failed | None:
    """The cached export in ``folder``; None when there is none (or only a stale failure)."""
    try:
        manifest = json.loads((folder / "manifest.json").read_text(encoding="utf-8"))
    except FileNotFoundError:
        return _cached_failure(folder, settings)
    root = folder / "files"
    return Done(
        [
            ExportFile(f["name"], root / f["name"], int(f["size"]), str(f["sha256"]))
            for f in manifest["files"]
        ]
    )


def _cached_failure(folder: Path, settings: Settings) -> Failed | None:
    try:
        error = json.loads((folder / "error.json").read_text(encoding="utf-8"))
    except FileNotFoundError:
        return None
    if error.get("limits") != limits_of(settings):
        return None
    return Failed(str(error["type"]), str(error["detail"]), list(error.get("errors", [])))


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as handle:
        for chunk in iter(lambda: handle.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


class Exporter:
    """Makes exports on at most ``DCSEG_MAX_CONCURRENT_EXPORTS`` threads, one child process
    each; a request for an export being made waits for the same one."""

    def __init__(self, settings: Settings, target: str = EXPORTER) -> None:
        self.settings = settings
        self.target = target
        self._pool = ThreadPoolExecutor(settings.max_concurrent_exports, "export")
        self._making: dict[Path, Future[None]] = {}
        self._children: set[Any] = set()
        self._lock = threading.Lock()
        self._closed = False

    def start(self, run: Path, folder: Path, selection: Selection) -> Future[None]:
        """The (new or running) making of the export into ``folder``."""
        with self._lock:
            running = self._making.get(folder)
            if running is not None:
                return running
            future = self._pool.submit(self._make, run, folder, selection)
            self._making[folder] = future
        future.add_done_callback(lambda _: self._forget(folder))
        return future

    def _forget(self, folder: Path) -> None:
        with self._lock:
            self._making.pop(folder, None)

    def close(self) -> None:
        """Kill running export processes and drop queued ones (API shutdown)."""
        with self._lock:
            self._closed = True
            children = list(self._children)
        for child in children:
            child.kill()
        self._pool.shutdown(wait=False, cancel_futures=True)

    def _make(self, run: Path, folder: Path, selection: Selection) -> None:
        if read_cached(folder, self.settings) is not None:
            return  # made by another replica (or thread) meanwhile
        tmp = folder.with_name(f".tmp-{folder.name}-{uuid.uuid4().hex[:8]}")
        (tmp / "files").mkdir(parents=True)
        try:
            started = time.monotonic()
            record = self._run_child(run, tmp, selection)
            record["seconds"] = round(time.monotonic() - started, 3)
            name = "manifest.json" if "files" in record else "error.json"
            if name == "error.json":  # a failure keeps no files
                shutil.rmtree(tmp / "files", ignore_errors=True)
            (tmp / name).write_text(json.dumps(record, indent=1), encoding="utf-8")
            _publish(tmp, folder)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)

    def _run_child(self, run: Path, tmp: Path, selection: Selection) -> dict[str, Any]:
        """Run the exporter in a child; the manifest or error record of its outcome."""
        out = tmp / "files"
        instances = None if selection.instance is None else [selection.instance]
        context = multiprocessing.get_context("spawn")
        child = context.Process(
            target=run_exporter,
            args=(self.target, str(run), str(out), selection.fmt, instances),
            name=f"export-{selection.fmt}",
            daemon=True,
        )
        with self._lock:
            if self._closed:
                return self._failure("export-error", "the server is shutting down")
            child.start()
            self._children.add(child)
        try:
            child.join(self.settings.export_time_limit_s)
            if child.is_alive():
                child.kill()
                child.join()
                limit = self.settings.export_time_limit_s
                return self._failure(
                    "export-timed-out",
                    f"the {selection.fmt} export took longer than {limit:g} s"
                    " (DCSEG_EXPORT_TIME_LIMIT_S)",
                )
        finally:
            with self._lock:
                self._children.discard(child)
        return self._outcome(tmp, out, selection)

    def _outcome(self, tmp: Path, out: Path, selection: Selection) -> dict[str, Any]:
        try:
            result = json.loads((tmp / "result.json").read_text(encoding="utf-8"))
        except FileNotFoundError:
            error_id = uuid.uuid4().hex[:12]
            logger.error("export child of %s died without a result (error id %s)", tmp, error_id)
            return self._failure("export-error", f"internal error {error_id}", error_id=error_id)
        if "files" not in result:
            return self._child_failure(result, selection)
        return self._files_record(out, [Path(p) for p in result["files"]], selection)

    def _child_failure(self, result: dict[str, Any], selection: Selection) -> dict[str, Any]:
        if result["type"] == "export-failed":
            errors = result["errors"]
            detail = f"cannot export {selection.fmt}: " + "; ".join(
                f"{e['path']}: {e['reason']}" for e in errors
            )
            return self._failure("export-failed", detail, errors=errors)
        error_id = result.get("error_id", "")
        return self._failure("export-error", f"internal error {error_id}", error_id=error_id)

    def _files_record(
        self, out: Path, paths: Sequence[Path], selection: Selection
    ) -> dict[str, Any]:
        root = out.resolve()
        files: list[dict[str, Any]] = []
        for path in paths:
            resolved = (out / path).resolve()
            if not resolved.is_relative_to(root) or not resolved.is_file():
                error_id = uuid.uuid4().hex[:12]
                logger.error("exporter returned %s outside %s (error id %s)", path, out, error_id)
                return self._failure("export-error", f"internal error {error_id}")
            size = resolved.stat().st_size
            rel = resolved.relative_to(root).as_posix()
            files.append({"name": rel, "size": size, "sha256": _sha256(resolved)})
        total = sum(int(f["size"]) for f in files)
        if total > self.settings.max_export_bytes:
            return self._failure(
                "export-too-large",
                f"the {selection.fmt} export would be {total} bytes, above"
                f" DCSEG_MAX_EXPORT_BYTES ({self.settings.max_export_bytes})",
            )
        return {"format": selection.fmt, "instance": selection.instance, "files": files}

    def _failure(self, slug: str, detail: str, **extra: Any) -> dict[str, Any]:
        return {
            "type": slug,
            "detail": detail,
            "limits": limits_of(self.settings),
            **extra,
        }


def _publish(tmp: Path, folder: Path) -> None:
    """Rename ``tmp`` to ``folder`` (replacing a stale failure); a whole export already there
    (another replica was faster) wins and ``tmp`` is dropped by the caller."""
    (tmp / "result.json").unlink(missing_ok=True)
    folder.parent.mkdir(parents=True, exist_ok=True)
    if (folder / "error.json").is_file():
        shutil.rmtree(folder, ignore_errors=True)
    try:
        os.rename(tmp, folder)
    except OSError:
        if not (folder / "manifest.json").is_file() and not (folder / "error.json").is_file():
            raise
