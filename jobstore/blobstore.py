"""Where uploads, stage outputs, manifests and artifacts live: the :class:`Storage` interface.

Two implementations: :class:`LocalStorage` (a directory shared by the API and the workers,
the embedded default; layout in :mod:`jobstore.contract`) and :class:`jobstore.s3.S3Storage`
(an S3-compatible bucket, one prefix per tenant; workers fetch into private scratch space).
The API and the worker go through this interface only; :func:`make_storage` picks one from
the settings.
"""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from jobstore.contract import MANIFEST, JobPaths, UploadPaths

if TYPE_CHECKING:
    from jobstore.settings import Settings
    from jobstore.store import Store

CHUNK = 1 << 20


@dataclass(frozen=True)
class StoredFile:
    """One file of a finished stage, as its job's manifest names it."""

    name: str
    """``<stage>/<path>``, the artifact name."""
    size: int
    sha256: str
    path: Path | None = None
    """Local storage: the file."""
    key: str | None = None
    """Object storage: the object key, relative to the tenant's prefix."""


class Storage(Protocol):
    """What the API and the workers store and read, whatever holds it."""

    backend: str
    """``local`` or ``s3``."""

    def setup(self) -> None:
        """Create what the storage needs (API startup): the folder or the bucket."""
        ...

    def check(self) -> None:
        """Raise unless the storage is reachable and writable (``/readyz``)."""
        ...

    def keep_upload(self, tenant: str, upload_id: str, tmp: Path) -> None:
        """Keep a validated upload: ``tmp`` holds ``archive`` and the extracted ``data/``."""
        ...

    def remove_upload(self, tenant: str, upload_id: str) -> None: ...

    def remove_job(self, tenant: str, job_id: str) -> None:
        """Delete every file of the job (its stage outputs and manifests)."""
        ...

    def manifest(self, tenant: str, job_id: str) -> dict[str, Any]:
        """The job's manifest ``{"stages": [...]}`` (no stages when none finished)."""
        ...

    def files(self, tenant: str, job_id: str) -> list[StoredFile]:
        """Every file of every finished stage, in stage order."""
        ...

    def read(self, tenant: str, item: StoredFile, start: int, end: int) -> Iterator[bytes]:
        """Bytes ``start..end`` (inclusive) of ``item``, in chunks."""
        ...

    def presign(self, tenant: str, item: StoredFile) -> str | None:
        """A URL that downloads ``item`` without the API for a short time; None if unsupported."""
        ...

    def tenant_bytes(self, store: Store, tenant: str) -> int:
        """Bytes the tenant stores (uploads plus job outputs), for its quota."""
        ...


def read_manifest_file(output: Path) -> dict[str, Any]:
    """The manifest in a job's local ``output`` folder (no stages when absent or unreadable)."""
    try:
        data: dict[str, Any] = json.loads((output / MANIFEST).read_text(encoding="utf-8"))
    except (FileNotFoundError, json.JSONDecodeError):
        return {"stages": []}
    return data


def manifest_files(manifest: dict[str, Any]) -> Iterator[tuple[str, dict[str, Any]]]:
    """``(name, {size, sha256, ...})`` of every file the manifest lists, in stage order."""
    for stage in manifest.get("stages", []):
        yield from sorted(stage.get("files", {}).items())


def read_local(path: Path, start: int, end: int) -> Iterator[bytes]:
    """Yield bytes ``start..end`` (inclusive) of ``path`` in chunks."""
    with path.open("rb") as handle:
        handle.seek(start)
        left = end - start + 1
        while left > 0:
            chunk = handle.read(min(CHUNK, left))
            if not chunk:
                break
            left -= len(chunk)
            yield chunk


class LocalStorage:
    """A directory shared by the API and every worker (``DCSEG_STORAGE_DIR``)."""

    backend = "local"

    def __init__(self, root: Path) -> None:
        self.root = root

    def setup(self) -> None:
        self.root.mkdir(parents=True, exist_ok=True)

    def check(self) -> None:
        import tempfile

        with tempfile.TemporaryFile(dir=self.root):
            pass

    def keep_upload(self, tenant: str, upload_id: str, tmp: Path) -> None:
        (tmp / "archive").unlink()
        os.rename(tmp, UploadPaths(self.root, upload_id).folder)

    def remove_upload(self, tenant: str, upload_id: str) -> None:
        shutil.rmtree(UploadPaths(self.root, upload_id).folder, ignore_errors=True)

    def remove_job(self, tenant: str, job_id: str) -> None:
        shutil.rmtree(JobPaths(self.root, job_id).folder, ignore_errors=True)

    def manifest(self, tenant: str, job_id: str) -> dict[str, Any]:
        return read_manifest_file(JobPaths(self.root, job_id).output)

    def files(self, tenant: str, job_id: str) -> list[StoredFile]:
        output = JobPaths(self.root, job_id).output
        root = output.resolve()
        found: list[StoredFile] = []
        for name, info in manifest_files(read_manifest_file(output)):
            path = (root / name).resolve()
            if path.is_relative_to(root) and path.is_file():
                found.append(StoredFile(name, int(info["size"]), str(info["sha256"]), path=path))
        return found

    def read(self, tenant: str, item: StoredFile, start: int, end: int) -> Iterator[bytes]:
        assert item.path is not None
        return read_local(item.path, start, end)

    def presign(self, tenant: str, item: StoredFile) -> str | None:
        return None

    def tenant_bytes(self, store: Store, tenant: str) -> int:
        used, job_ids = store.tenant_storage(tenant)
        for job_id in job_ids:
            used += sum(int(info["size"]) for _, info in manifest_files(self.manifest("", job_id)))
        return used


def make_storage(settings: Settings) -> Storage:
    """The storage the settings configure (``DCSEG_STORAGE_BACKEND``)."""
    if settings.storage_backend == "s3":
        from jobstore.s3 import S3Storage

        return S3Storage.from_settings(settings)
    return LocalStorage(settings.storage_dir)
