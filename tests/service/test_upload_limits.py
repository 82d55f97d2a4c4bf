"""Uploads within their limits (:mod:`service.uploads`): tenant quotas, free space and a full
disk (507), upload expiry, and a bounded validation pool that leaves ``/healthz`` alone."""

from __future__ import annotations

import errno
import json
import shutil
import threading
from concurrent.futures import Future, ThreadPoolExecutor
from datetime import timedelta
from pathlib import Path
from typing import IO, Any

import anyio.to_thread
from sqlalchemy import func, select, update

import dcseg.io.archive
from jobstore.contract import JobPaths
from jobstore.models import Upload, utcnow
from jobstore.settings import Settings
from service import uploads as service_uploads
from tests.service.conftest import (
    AUTH_A,
    AUTH_B,
    TAR,
    TestClient,
    assert_problem,
    state_of,
    wait_for,
)

BOUND_S = 60.0
"""Upper bound on waits, so a regression fails instead of hanging (not a timing assert)."""


def _nothing_stored(client: TestClient) -> None:
    state = state_of(client)
    folder = state.settings.storage_dir / "uploads"
    assert not folder.exists() or list(folder.iterdir()) == []
    with state.store.session() as s:
        assert s.scalar(select(func.count()).select_from(Upload)) == 0


def _upload(client: TestClient, body: bytes, **headers: str) -> Any:
    return client.post("/v1/uploads", content=body, headers={**AUTH_A, **TAR, **headers})


def test_enospc_while_receiving_answers_507_and_stores_nothing(client, scene_tar, monkeypatch):
    """Defect: a full disk while the body is written must answer 507 with nothing left."""

    def full(out: IO[bytes], data: bytes) -> None:
        out.write(data[: len(data) // 2])
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(service_uploads, "write_chunk", full, raising=False)
    body = assert_problem(_upload(client, scene_tar), 507)
    assert body["type"].endswith("insufficient-storage")
    _nothing_stored(client)


def test_enospc_during_extraction_answers_507_not_corrupt_archive(client, scene_tar, monkeypatch):
    """Defect: "a full disk during extraction answers 422 corrupt archive"; map ENOSPC to 507
    and keep the store consistent."""
    real_copy = dcseg.io.archive._copy
    calls = [0]

    def copy_then_fill(source: Any, target: Path, name: str, budget: Any) -> None:
        calls[0] += 1
        if calls[0] < 3:
            return real_copy(source, target, name, budget)
        target.write_bytes(b"half")
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(dcseg.io.archive, "_copy", copy_then_fill)
    body = assert_problem(_upload(client, scene_tar), 507)
    assert body["type"].endswith("insufficient-storage")
    assert "corrupt" not in body["detail"]
    _nothing_stored(client)


def test_upload_beyond_the_tenant_quota_answers_507(make_client, scene_tar):
    """Defect: "No per-tenant storage quota"; an upload past it answers 507 and is not kept."""
    client = make_client(tenant_storage_quota_bytes=int(len(scene_tar) * 1.5))
    assert _upload(client, scene_tar).status_code == 201
    body = assert_problem(_upload(client, scene_tar), 507)
    assert body["type"].endswith("storage-quota-exceeded")
    assert body["quota"] == int(len(scene_tar) * 1.5) and 0 < body["used"] <= len(scene_tar)
    with state_of(client).store.session() as s:
        assert s.scalar(select(func.count()).select_from(Upload)) == 1
    assert len(list((state_of(client).settings.storage_dir / "uploads").iterdir())) == 1
    other = client.post("/v1/uploads", content=scene_tar, headers={**AUTH_B, **TAR})
    assert other.status_code == 201, other.text  # the quota is per tenant


def test_job_outputs_count_toward_the_tenant_quota(make_client, scene_tar):
    """Defect: the quota counts a tenant's job outputs as well as its uploads."""
    client = make_client(tenant_storage_quota_bytes=3 * len(scene_tar))
    upload = _upload(client, scene_tar).json()
    job = client.post("/v1/jobs", json={"upload_id": upload["id"]}, headers=AUTH_A).json()
    paths = JobPaths(state_of(client).settings.storage_dir, job["id"])
    paths.output.mkdir(parents=True)
    manifest = {"stages": [{"name": "reconstruct", "files": {"a": {"size": 2 * len(scene_tar)}}}]}
    paths.manifest.write_text(json.dumps(manifest), encoding="utf-8")
    assert assert_problem(_upload(client, scene_tar), 507)["type"].endswith("quota-exceeded")


def test_low_free_space_answers_507_before_reading_the_body(client, scene_tar, monkeypatch):
    """Defect: "no free-space check"; too little free space answers 507 up front."""
    real = shutil.disk_usage

    def nearly_full(path: Any) -> Any:
        usage = real(path)
        return type(usage)(usage.total, usage.total - 1000, 1000)

    monkeypatch.setattr(shutil, "disk_usage", nearly_full)
    body = assert_problem(_upload(client, scene_tar), 507)
    assert body["type"].endswith("insufficient-storage")
    _nothing_stored(client)


def _backdate_uploads(client: TestClient, days: float) -> None:
    with state_of(client).store.session() as s:
        s.execute(update(Upload).values(created_at=utcnow() - timedelta(days=days)))


def test_unused_uploads_expire_and_uploads_of_jobs_stay(make_client, scene_tar):
    """Defect: "no upload expiry"; unused old uploads are swept, those of jobs never."""
    client = make_client(upload_expiry_s=3600.0, housekeeping_interval_s=0.05)
    unused, used, fresh = (_upload(client, scene_tar).json()["id"] for _ in range(3))
    job = client.post("/v1/jobs", json={"upload_id": used}, headers=AUTH_A)
    assert job.status_code == 202, job.text
    _backdate_uploads(client, days=2)
    with state_of(client).store.session() as s:
        s.execute(update(Upload).where(Upload.id == fresh).values(created_at=utcnow()))
    storage = state_of(client).settings.storage_dir / "uploads"
    wait_for(lambda: not (storage / unused).exists(), timeout=BOUND_S)  # row first, then files
    assert_problem(client.get(f"/v1/uploads/{unused}", headers=AUTH_A), 404)
    for kept in (used, fresh):
        assert client.get(f"/v1/uploads/{kept}", headers=AUTH_A).status_code == 200
        assert (storage / kept).is_dir()


class _Gate:
    """A stand-in for ``extract_and_validate`` that holds its thread until released."""

    def __init__(self) -> None:
        self.entered = 0
        self.release = threading.Event()
        self.real = service_uploads.extract_and_validate

    def __call__(self, archive: Path, dest: Path, settings: Settings) -> dict[str, Any]:
        self.entered += 1
        assert self.release.wait(BOUND_S), "never released"
        return self.real(archive, dest, settings)


async def _shrink_default_threadpool() -> None:
    anyio.to_thread.current_default_thread_limiter().total_tokens = 2


def test_health_answers_while_upload_validations_saturate_the_pool(
    make_client, scene_tar, monkeypatch
):
    """Defect: "Uploads' extraction and validation share the threadpool with every sync route,
    including /healthz; ~40 concurrent uploads stall the API. Bounded executor; async health."
    Here the shared threadpool has 2 threads and 2 uploads hold validation: health still
    answers, a third upload gets 503 + Retry-After, the two finish once released."""
    client = make_client(max_upload_validations=1, max_pending_uploads=2)
    client.portal.call(_shrink_default_threadpool)
    gate = _Gate()
    monkeypatch.setattr(service_uploads, "extract_and_validate", gate)
    tmp_folders = state_of(client).settings.storage_dir / "uploads"
    with ThreadPoolExecutor(4) as pool:
        held: list[Future[Any]] = [pool.submit(_upload, client, scene_tar) for _ in range(2)]
        try:
            wait_for(lambda: gate.entered >= 1, timeout=BOUND_S)
            wait_for(lambda: len(list(tmp_folders.glob(".tmp-*"))) == 2, timeout=BOUND_S)
            health = pool.submit(client.get, "/healthz").result(timeout=BOUND_S)
            assert health.status_code == 200 and health.json()["status"] == "ok"
            ready = pool.submit(client.get, "/readyz").result(timeout=BOUND_S)
            assert ready.status_code == 200, ready.text
            extra = pool.submit(_upload, client, scene_tar).result(timeout=BOUND_S)
            body = assert_problem(extra, 503)
            assert body["type"].endswith("too-many-uploads")
            assert int(extra.headers["retry-after"]) >= 1
            assert gate.entered == 1  # the second waits for the single validation thread
        finally:
            gate.release.set()
        assert [f.result(timeout=BOUND_S).status_code for f in held] == [201, 201]
    assert _upload(client, scene_tar).status_code == 201  # slots were given back


def test_full_disk_is_recognised_behind_wrapping_errors():
    """ENOSPC/EDQUOT and SQLite's "database or disk is full" count as a full disk, also when
    wrapped (safe_extract's InputError, SQLAlchemy's OperationalError); other errors do not."""
    import sqlite3

    from sqlalchemy.exc import OperationalError

    def wrapped(inner: BaseException) -> BaseException:
        try:
            try:
                raise inner
            except OSError:
                raise ValueError("corrupt or unreadable archive") from None
        except ValueError as outer:
            return outer

    assert service_uploads.is_disk_full(wrapped(OSError(errno.ENOSPC, "full")))
    assert service_uploads.is_disk_full(OSError(errno.EDQUOT, "quota"))
    assert not service_uploads.is_disk_full(wrapped(OSError(errno.EIO, "io")))
    full = sqlite3.OperationalError("database or disk is full")
    full.sqlite_errorcode = sqlite3.SQLITE_FULL
    assert service_uploads.is_disk_full(OperationalError("INSERT", {}, full))
    assert not service_uploads.is_disk_full(OperationalError("INSERT", {}, ValueError("x")))
