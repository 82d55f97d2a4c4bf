"""Exports of a finished job (``dcseg.export``), made on demand and cached in the job's folder.

An export is made once per (selection, format, options): the whole scene or one instance. The
first request starts it on a thread of :class:`Exporter`, which runs ``export_run`` in a child
process of its own (``python -m service.export_child``: the API process never imports the
exporters' dependencies, an export cannot block the event loop, and one past
``DCSEG_EXPORT_TIME_LIMIT_S`` is killed).
The child writes into a temporary folder; its files are hashed, checked against
``DCSEG_MAX_EXPORT_BYTES`` and renamed into place with a manifest, so a reader sees a whole
export or none. A failure is cached the same way (``error.json``) for the limits it met.

Layout inside ``jobs/<job_id>/``::

    exports/<scene|instance-K>/<format>/manifest.json   {format, instance, files: [...]}
    exports/<scene|instance-K>/<format>/files/...       the exported files
    exports/<scene|instance-K>/<format>/error.json      a failed export {type, detail, limits}
"""

from __future__ import annotations

import functools
import hashlib
import json
import logging
import os
import shutil
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any, get_args

from jobstore.blobstore import Storage, StoredFile
from jobstore.contract import JobPaths
from jobstore.settings import Settings
from service.export_child import RUN
from service.schemas import ExportFormat

logger = logging.getLogger(__name__)

FORMATS: tuple[str, ...] = get_args(ExportFormat)
"""Export formats the service offers (those of ``dcseg.export``)."""
EXPORTER = "dcseg.export:export_run"
"""``module:function`` the child process calls: ``(run, out, fmt, *, instances) -> paths``."""


RunGetter = Callable[[], Path]
"""Gives the local folder of the finished run an export reads (called on an export thread)."""


def cache_root(settings: Settings, job_id: str) -> Path:
    """Where a job's exports are cached: ``jobs/<id>/exports/`` of the API's storage folder."""
    return JobPaths(settings.storage_dir, job_id).folder / "exports"


def remove_cached(settings: Settings, job_id: str) -> None:
    """Delete a job's cached exports (with object storage they live on the API's disk)."""
    shutil.rmtree(cache_root(settings, job_id), ignore_errors=True)


def run_getter(storage: Storage, tenant: str, job_id: str, settings: Settings) -> RunGetter:
    """The job's segment stage folder: read in place from local storage; fetched once from
    object storage into ``exports/run/`` of the cache (SHA-256 checked)."""
    if storage.backend == "local":
        folder = JobPaths(settings.storage_dir, job_id).output / RUN
        return lambda: folder
    dest = cache_root(settings, job_id) / "run"
    return functools.partial(fetch_run, storage, tenant, job_id, dest)


def fetch_run(storage: Storage, tenant: str, job_id: str, dest: Path) -> Path:
    """Copy the files of the job's segment stage into ``dest`` (once; renamed into place)."""
    if dest.is_dir():
        return dest
    tmp = dest.with_name(f".tmp-run-{uuid.uuid4().hex[:8]}")
    try:
        for item in storage.files(tenant, job_id):
            if item.name.startswith(RUN + "/"):
                _fetch_file(storage, tenant, item, tmp / item.name.removeprefix(RUN + "/"))
        tmp.mkdir(parents=True, exist_ok=True)
        os.rename(tmp, dest)
    except OSError:
        if not dest.is_dir():  # else another thread fetched it first
            raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return dest


def _fetch_file(storage: Storage, tenant: str, item: StoredFile, target: Path) -> None:
    if ".." in Path(item.name).parts:
        raise OSError(f"unsafe stored name {item.name!r}")
    target.parent.mkdir(parents=True, exist_ok=True)
    digest = hashlib.sha256()
    with target.open("wb") as out:
        for chunk in storage.read(tenant, item, 0, item.size - 1) if item.size else ():
            digest.update(chunk)
            out.write(chunk)
    if digest.hexdigest() != item.sha256:
        raise OSError(f"{item.name}: SHA-256 mismatch while fetching it from storage")


@dataclass(frozen=True)
class Selection:
    """What an export holds: the whole scene (``instance`` None) or one object."""

    fmt: str
    instance: int | None = None
    options: tuple[tuple[str, str | int], ...] = ()
    """``ExportOptions`` fields that differ from their defaults, sorted by name."""

    @property
    def folder_name(self) -> str:
        return "scene" if self.instance is None else f"instance-{self.instance}"

    @property
    def variant(self) -> str:
        """The cache folder of the format and options: ``ply``, ``ply.colour-class.sh_degree-3``."""
        return self.fmt + "".join(f".{name}-{value}" for name, value in self.options)

    def folder(self, root: Path) -> Path:
        """The cache folder of this export under a job's :func:`cache_root`."""
        return root / self.folder_name / self.variant


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
    ``export-timed-out`` or ``export-error`` (an internal error; never cached)."""
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
        self._making: dict[Path, Future[Failed | None]] = {}
        self._children: set[subprocess.Popen[bytes]] = set()
        self._lock = threading.Lock()
        self._closed = False

    def start(self, run: RunGetter, folder: Path, selection: Selection) -> Future[Failed | None]:
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

    def _make(self, get_run: RunGetter, folder: Path, selection: Selection) -> Failed | None:
        """Make the export and cache its outcome; an internal error (a crash, a shutdown) is
        not cached but returned, so the next request tries again."""
        if read_cached(folder, self.settings) is not None:
            return None  # made by another replica (or thread) meanwhile
        run = get_run()
        tmp = folder.with_name(f".tmp-{folder.name}-{uuid.uuid4().hex[:8]}")
        (tmp / "files").mkdir(parents=True)
        try:
            started = time.monotonic()
            record = self._run_child(run, tmp, selection)
            record["seconds"] = round(time.monotonic() - started, 3)
            if record.get("type") == "export-error":
                return Failed("export-error", str(record["detail"]), [])
            name = "manifest.json" if "files" in record else "error.json"
            if name == "error.json":  # a failure keeps no files
                shutil.rmtree(tmp / "files", ignore_errors=True)
            (tmp / name).write_text(json.dumps(record, indent=1), encoding="utf-8")
            _publish(tmp, folder)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
        return None

    def _run_child(self, run: Path, tmp: Path, selection: Selection) -> dict[str, Any]:
        """Run the exporter in a child; the manifest or error record of its outcome."""
        out = tmp / "files"
        job = {
            "target": self.target,
            "run": str(run),
            "out": str(out),
            "fmt": selection.fmt,
            "instances": None if selection.instance is None else [selection.instance],
            "options": dict(selection.options),
        }
        command = [sys.executable, "-m", "service.export_child", json.dumps(job)]
        with self._lock:
            if self._closed:
                return self._failure("export-error", "the server is shutting down")
            child = subprocess.Popen(command, stdin=subprocess.DEVNULL, env=_child_env())
            self._children.add(child)
        try:
            child.wait(self.settings.export_time_limit_s)
        except subprocess.TimeoutExpired:
            child.kill()
            child.wait()
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
        root = out.resolve()  # the child names files relative to ``out``
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
        options = dict(selection.options)
        return {
            "format": selection.fmt,
            "instance": selection.instance,
            "options": options,
            "files": files,
        }

    def _failure(self, slug: str, detail: str, **extra: Any) -> dict[str, Any]:
        return {
            "type": slug,
            "detail": detail,
            "limits": limits_of(self.settings),
            **extra,
        }


def _child_env() -> dict[str, str]:
    """The environment of an export child: this one, with this process's import path (as
    multiprocessing gives a spawned child), so it imports the same ``service`` and ``dcseg``."""
    return {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}


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
