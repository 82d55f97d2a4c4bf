"""Where a worker runs a job's stages: the shared storage folder itself, or private scratch.

:class:`LocalWorkspace` (``DCSEG_STORAGE_BACKEND=local``) works in ``jobs/<id>/output/`` of
the shared folder: a stage is renamed into place and appended to ``manifest.json``.
:class:`ScratchWorkspace` (``s3``) fetches the upload and the finished stages' files into
``<DCSEG_SCRATCH_DIR>/<job_id>/`` (checking each file's SHA-256), uploads each new stage's
files under the run's own attempt folder, then commits the stage's manifest object last; the
scratch folder is bounded by ``DCSEG_SCRATCH_MAX_BYTES`` and removed when the job stops.
"""

from __future__ import annotations

import json
import os
import shutil
import uuid
from collections.abc import Callable
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any, Protocol

from jobstore.blobstore import LocalStorage, Storage
from jobstore.contract import MANIFEST, JobPaths, UploadPaths

if TYPE_CHECKING:
    from jobstore.models import Upload
    from jobstore.s3 import S3Storage
    from jobstore.settings import Settings

MANIFEST_VERSION = 1


class ScratchFull(Exception):
    """The job needs more scratch space than ``DCSEG_SCRATCH_MAX_BYTES`` allows."""


class CommitRefused(Exception):
    """Another run committed the stage first (this worker's lease had expired)."""


class Workspace(Protocol):
    output: Path
    """The folder holding the finished stages (``<stage>/...``) and the stage being run."""

    def inputs(self, upload: Upload) -> Path:
        """The extracted upload's root folder."""
        ...

    def manifest(self) -> dict[str, Any]:
        """The job's manifest; the finished stages' files are in :attr:`output` after it."""
        ...

    def parent_manifest(self) -> dict[str, Any]:
        """The parent job's manifest (no stages without a parent)."""
        ...

    def reuse(self, entry: dict[str, Any], dest: Path) -> None:
        """Put the parent's files of stage ``entry`` into ``dest``; OSError/ValueError when a
        file is gone or differs from the parent's manifest."""
        ...

    def commit(self, entry: dict[str, Any], tmp: Path, manifest: dict[str, Any]) -> None:
        """Make stage ``entry`` (its files in ``tmp``) finished: store its files, then its
        manifest; appends ``entry`` to ``manifest``."""
        ...

    def close(self) -> None: ...


def write_manifest(paths: JobPaths, manifest: dict[str, Any]) -> None:
    tmp = paths.output / f".{MANIFEST}.tmp"
    tmp.write_text(json.dumps(manifest, indent=2, sort_keys=True), encoding="utf-8")
    os.replace(tmp, paths.manifest)


def read_manifest(paths: JobPaths) -> dict[str, Any]:
    try:
        data: dict[str, Any] = json.loads(paths.manifest.read_text(encoding="utf-8"))
        return data
    except FileNotFoundError:
        return {"version": MANIFEST_VERSION, "job_id": paths.job_id, "stages": []}


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


class LocalWorkspace:
    """The job's output folder in the shared storage directory."""

    def __init__(self, root: Path, job_id: str, parent_id: str | None) -> None:
        self.paths = JobPaths(root, job_id)
        self.parent = JobPaths(root, parent_id) if parent_id else None
        self.root = root
        self.output = self.paths.output

    def inputs(self, upload: Upload) -> Path:
        return UploadPaths(self.root, upload.id).data / str(upload.summary.get("root", "."))

    def manifest(self) -> dict[str, Any]:
        self.output.mkdir(parents=True, exist_ok=True)
        for stale in self.output.glob(".tmp-*"):
            shutil.rmtree(stale, ignore_errors=True)
        return read_manifest(self.paths)

    def parent_manifest(self) -> dict[str, Any]:
        return read_manifest(self.parent) if self.parent else {"stages": []}

    def reuse(self, entry: dict[str, Any], dest: Path) -> None:
        assert self.parent is not None
        _link_files(self.parent.output, entry["files"], entry["name"], dest)

    def commit(self, entry: dict[str, Any], tmp: Path, manifest: dict[str, Any]) -> None:
        final = self.output / entry["name"]
        if final.exists():  # left by a crash between rename and manifest write
            shutil.rmtree(final)
        os.rename(tmp, final)
        manifest["stages"].append(entry)
        write_manifest(self.paths, manifest)

    def close(self) -> None:
        pass


def tree_bytes(folder: Path) -> int:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file() and not p.is_symlink())


class ScratchWorkspace:
    """A private scratch folder filled from, and committed to, object storage."""

    def __init__(
        self,
        storage: S3Storage,
        settings: Settings,
        tenant: str,
        job_id: str,
        parent_id: str | None,
        lease_check: Callable[[], None],
    ) -> None:
        self.storage, self.settings, self.tenant = storage, settings, tenant
        self.job_id, self.parent_id, self.lease_check = job_id, parent_id, lease_check
        self.folder = settings.scratch_dir / job_id
        shutil.rmtree(self.folder, ignore_errors=True)  # a previous run's, on this worker
        self.output = self.folder / "output"
        self.output.mkdir(parents=True)
        self.attempt = uuid.uuid4().hex[:12]
        self.used = 0

    def _reserve(self, size: int, what: str) -> None:
        limit = self.settings.scratch_max_bytes
        if self.used + size > limit:
            raise ScratchFull(
                f"job {self.job_id} needs {self.used + size:,} bytes of scratch space for {what}; "
                f"the worker allows {limit:,} (setting DCSEG_SCRATCH_MAX_BYTES)"
            )
        self.used += size

    def inputs(self, upload: Upload) -> Path:
        from dcseg.io.archive import safe_extract

        archive = self.folder / "upload.archive"
        extracted = upload.stored_bytes or 0  # measured when the upload was validated
        self._reserve(upload.size + extracted, f"upload {upload.id} and its extraction")
        key = self.storage.key(self.tenant, f"uploads/{upload.id}/archive")
        self.storage.fetch(key, archive, upload.size, upload.sha256)
        data = self.folder / "input"
        safe_extract(
            archive,
            data,
            max_entries=self.settings.max_archive_entries,
            max_total_bytes=self.settings.max_extracted_bytes,
            max_directory_bytes=self.settings.max_archive_directory_bytes,
            max_header_bytes=self.settings.max_archive_header_bytes,
        )
        archive.unlink()
        self.used += tree_bytes(data) - upload.size - extracted
        return data / str(upload.summary.get("root", "."))

    def _fetch_stage(self, entry: dict[str, Any], dest: Path) -> None:
        name = entry["name"]
        for file_name, info in sorted(entry.get("files", {}).items()):
            self._reserve(int(info["size"]), file_name)
            target = dest / Path(file_name).relative_to(name)
            key = self.storage.key(self.tenant, info["key"])
            self.storage.fetch(key, target, int(info["size"]), str(info["sha256"]))

    def manifest(self) -> dict[str, Any]:
        manifest = self.storage.manifest(self.tenant, self.job_id)
        for entry in manifest["stages"]:
            self._fetch_stage(entry, self.output / entry["name"])
        return manifest

    def parent_manifest(self) -> dict[str, Any]:
        if self.parent_id is None:
            return {"stages": []}
        return self.storage.manifest(self.tenant, self.parent_id)

    def reuse(self, entry: dict[str, Any], dest: Path) -> None:
        from botocore.exceptions import ClientError

        try:
            self._fetch_stage(entry, dest)
        except ClientError as error:
            raise OSError(f"a file of the parent's stage {entry['name']} is gone") from error

    def commit(self, entry: dict[str, Any], tmp: Path, manifest: dict[str, Any]) -> None:
        name = entry["name"]
        self._reserve(tree_bytes(tmp), f"the outputs of stage {name}")
        self.lease_check()
        attempt = f"jobs/{self.job_id}/attempts/{self.attempt}"
        for file_name, info in entry["files"].items():
            info["key"] = f"{attempt}/{file_name}"
            path = tmp / Path(file_name).relative_to(name)
            self.storage.put_file(self.storage.key(self.tenant, info["key"]), path)
        self.lease_check()
        stage_key = self.storage.key(
            self.tenant, f"jobs/{self.job_id}/stages/{entry['index']:02d}-{name}.json"
        )
        if not self.storage.put_json(stage_key, entry, only_new=True):
            raise CommitRefused(f"stage {name} of job {self.job_id} was committed by another run")
        os.rename(tmp, self.output / name)
        manifest["stages"].append(entry)

    def close(self) -> None:
        shutil.rmtree(self.folder, ignore_errors=True)

    def __enter__(self) -> ScratchWorkspace:
        return self

    def __exit__(
        self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()


def clear_scratch(settings: Settings) -> None:
    """Empty the worker's scratch folder (object storage only; at worker start: the folder is
    private to one worker, so whatever is in it belongs to no running job)."""
    if settings.storage_backend != "s3" or not settings.scratch_dir.is_dir():
        return
    for child in settings.scratch_dir.iterdir():
        if child.is_dir():
            shutil.rmtree(child, ignore_errors=True)
        else:
            child.unlink(missing_ok=True)


def open_workspace(
    storage: Storage,
    settings: Settings,
    tenant: str,
    job_id: str,
    parent_id: str | None,
    lease_check: Callable[[], None],
) -> Workspace:
    """The workspace of ``storage``'s kind for one run of a job."""
    if isinstance(storage, LocalStorage):
        return LocalWorkspace(storage.root, job_id, parent_id)
    from jobstore.s3 import S3Storage

    assert isinstance(storage, S3Storage)
    return ScratchWorkspace(storage, settings, tenant, job_id, parent_id, lease_check)
