"""Receiving an upload: stream to disk under a size cap, check the digest, extract, validate.

Everything happens in ``uploads/.tmp-<id>/``, renamed to ``uploads/<id>/`` only once the
upload is valid, so a failed upload leaves nothing behind. Extraction and validation run on
a :class:`ValidationPool` of their own; free space and the tenant's quota are checked before
the body is read and again once it is extracted; a full disk answers 507.
"""

from __future__ import annotations

import base64
import binascii
import errno
import hashlib
import logging
import re
import shutil
import sqlite3
from collections.abc import AsyncIterator, Callable, Iterator
from contextlib import contextmanager
from datetime import timedelta
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any, TypeVar

import anyio
import anyio.to_thread
from fastapi.concurrency import run_in_threadpool

from jobstore.blobstore import Storage
from jobstore.contract import input_digests, input_layout
from jobstore.models import utcnow
from jobstore.settings import Settings
from jobstore.store import Store, UploadInUse
from service.problems import ApiProblem

if TYPE_CHECKING:
    from service.deps import AppState

logger = logging.getLogger(__name__)

T = TypeVar("T")

ACCEPTED_TYPES = frozenset(
    {"application/zip", "application/x-tar", "application/gzip", "application/x-gzip"}
)
"""Upload body media types; anything else answers 415."""

_FLUSH = 1 << 20
_HEX64 = re.compile(r"^[0-9a-f]{64}$")
_REPR_DIGEST = re.compile(r"(?:^|,)\s*sha-256\s*=\s*:([A-Za-z0-9+/=]+):")


def media_type(content_type: str | None) -> str:
    return (content_type or "").split(";")[0].strip().lower()


def expected_digest(repr_digest: str | None, sha256_param: str | None) -> str | None:
    """The hex SHA-256 the client announced (``Repr-Digest`` or ``?sha256=``), if any."""
    digests: list[str] = []
    if sha256_param is not None:
        if not _HEX64.match(sha256_param.lower()):
            raise ApiProblem(400, "sha256 must be 64 hexadecimal digits", slug="bad-digest")
        digests.append(sha256_param.lower())
    if repr_digest is not None:
        match = _REPR_DIGEST.search(repr_digest)
        if match is None:
            raise ApiProblem(
                400, "Repr-Digest must contain sha-256=:<base64>: (RFC 9530)", slug="bad-digest"
            )
        try:
            raw = base64.b64decode(match.group(1), validate=True)
        except binascii.Error:
            raise ApiProblem(
                400, "Repr-Digest sha-256 is not valid base64", slug="bad-digest"
            ) from None
        if len(raw) != 32:
            raise ApiProblem(400, "Repr-Digest sha-256 must be 32 bytes", slug="bad-digest")
        digests.append(raw.hex())
    if len(set(digests)) > 1:
        raise ApiProblem(400, "Repr-Digest and sha256 disagree", slug="bad-digest")
    return digests[0] if digests else None


def too_large(limit: int) -> ApiProblem:
    return ApiProblem(
        413, f"upload is larger than {limit:,} bytes", slug="upload-too-large", limit=limit
    )


def upload_request_hash(content_type: str, sha256: str) -> str:
    """What ties an ``Idempotency-Key`` to an upload: its media type and body digest."""
    return hashlib.sha256(f"{content_type}\n{sha256}".encode()).hexdigest()


def write_chunk(out: IO[bytes], data: bytes) -> None:
    out.write(data)


async def receive(chunks: AsyncIterator[bytes], target: Path, limit: int) -> tuple[int, str]:
    """Write the body to ``target`` in chunks; returns ``(size, sha256)``; 413 past ``limit``."""
    digest = hashlib.sha256()
    size = 0
    buffer = bytearray()
    with target.open("wb") as out:
        async for chunk in chunks:
            size += len(chunk)
            if size > limit:
                raise too_large(limit)
            digest.update(chunk)
            buffer += chunk
            if len(buffer) >= _FLUSH:
                await run_in_threadpool(write_chunk, out, bytes(buffer))
                buffer.clear()
        if buffer:
            await run_in_threadpool(write_chunk, out, bytes(buffer))
    return size, digest.hexdigest()


def _public(path: str, hide: list[tuple[str, str]]) -> str:
    for prefix, replacement in hide:
        if path == prefix:
            return replacement or "."
        if path.startswith(prefix + "/"):
            return replacement + path[len(prefix) + 1 :]
    return path


def _reason(reason: str, hide: list[tuple[str, str]]) -> str:
    for prefix, replacement in hide:
        reason = reason.replace(prefix + "/", replacement).replace(prefix, replacement or ".")
    return reason


def extract_and_validate(archive: Path, dest: Path, settings: Settings) -> dict[str, Any]:
    """Extract ``archive`` into ``dest`` and validate it; 422 listing every problem.

    Returns the validation summary plus which optional inputs were found.
    """
    from dcseg.errors import InputError
    from dcseg.inputs import RunInputs
    from dcseg.io.archive import safe_extract
    from dcseg.io.validate import validate_inputs

    hide = [(str(dest.resolve()), ""), (str(dest), ""), (str(archive), "upload")]
    try:
        root = safe_extract(
            archive,
            dest,
            max_entries=settings.max_archive_entries,
            max_total_bytes=settings.max_extracted_bytes,
            max_directory_bytes=settings.max_archive_directory_bytes,
            max_header_bytes=settings.max_archive_header_bytes,
        )
    except InputError as error:
        raise invalid_upload(error.problems, hide) from None
    hide = [(str(root.resolve()), ""), (str(root), ""), *hide]
    layout = input_layout(root)
    report = validate_inputs(RunInputs(**layout), max_pixels=settings.max_validation_pixels)
    if report.problems:
        raise invalid_upload(report.problems, hide)
    found = {
        name: str(path.relative_to(root))
        for name, path in layout.items()
        if path is not None and name != "capture"
    }
    return {
        **report.summary,
        "inputs": found,
        "digests": input_digests(root),
        "root": str(root.relative_to(dest)),
    }


_SETTING_OF_LIMIT = {
    "max_entries": "max_archive_entries",
    "max_total_bytes": "max_extracted_bytes",
    "max_directory_bytes": "max_archive_directory_bytes",
    "max_header_bytes": "max_archive_header_bytes",
    "max_pixels": "max_validation_pixels",
}
"""The setting behind each limit argument of ``safe_extract`` / ``validate_inputs``."""


def _with_setting(problem: Any, reason: str) -> str:
    """``reason``, naming the setting when the problem is a limit that a setting sets."""
    from dcseg.io.limits import LimitProblem

    if isinstance(problem, LimitProblem) and problem.limit in _SETTING_OF_LIMIT:
        setting = _SETTING_OF_LIMIT[problem.limit]
        return f"{reason} (setting {setting}, environment DCSEG_{setting.upper()})"
    return reason


def invalid_upload(problems: Any, hide: list[tuple[str, str]]) -> ApiProblem:
    errors = [
        {"path": _public(p.path, hide), "reason": _with_setting(p, _reason(p.reason, hide))}
        for p in problems
    ]
    detail = "; ".join(f"{e['path']}: {e['reason']}" for e in errors[:5])
    if len(errors) > 5:
        detail += f"; and {len(errors) - 5} more"
    return ApiProblem(
        422,
        f"the upload is not a usable capture: {detail}",
        slug="invalid-upload",
        title="Invalid upload",
        errors=errors,
    )


def remove(path: Path) -> None:
    shutil.rmtree(path, ignore_errors=True)


# ----- storage: a full disk, free space, quotas -----

_FULL_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT})


def _chain(error: BaseException) -> Iterator[BaseException]:
    """``error``, then what it wraps (SQLAlchemy's ``orig``), was raised from or during."""
    seen: set[int] = set()
    current: BaseException | None = error
    while current is not None and id(current) not in seen:
        seen.add(id(current))
        yield current
        orig = getattr(current, "orig", None)
        if isinstance(orig, BaseException):
            current = orig
        else:
            current = current.__cause__ or current.__context__


def _full(error: BaseException) -> bool:
    if isinstance(error, OSError) and error.errno in _FULL_ERRNOS:
        return True
    return getattr(error, "sqlite_errorcode", None) == sqlite3.SQLITE_FULL


def is_disk_full(error: BaseException) -> bool:
    """Whether ``error`` or an exception behind it is a full disk or quota (ENOSPC, EDQUOT,
    SQLITE_FULL), also when something turned it into another error, as ``safe_extract``
    does with every OSError."""
    return any(_full(e) for e in _chain(error))


def insufficient_storage(detail: str, **extensions: Any) -> ApiProblem:
    return ApiProblem(507, detail, slug="insufficient-storage", **extensions)


@contextmanager
def disk_full_as_507() -> Iterator[None]:
    """Answer 507 (RFC 4918 Insufficient Storage) when the storage fills up inside."""
    try:
        yield
    except Exception as error:
        if not is_disk_full(error):
            raise
        logger.warning("storage full while receiving an upload: %s", error)
        raise insufficient_storage("the storage is full; the upload was not kept") from None


def check_free_space(settings: Settings, adding: int) -> None:
    """507 unless ``adding`` more bytes leave ``min_free_bytes`` free on the storage volume."""
    free = shutil.disk_usage(settings.storage_dir).free
    if free - adding < settings.min_free_bytes:
        raise insufficient_storage(
            f"the storage has {free:,} bytes free and must keep {settings.min_free_bytes:,}",
            free=free,
        )


def check_quota(settings: Settings, used: int, adding: int) -> None:
    """507 when ``adding`` bytes would take the tenant past its quota."""
    quota = settings.tenant_storage_quota_bytes
    if quota and used + adding > quota:
        raise ApiProblem(
            507,
            f"the tenant stores {used:,} bytes; {adding:,} more would exceed its quota of "
            f"{quota:,} (delete uploads or jobs)",
            slug="storage-quota-exceeded",
            title="Storage quota exceeded",
            quota=quota,
            used=used,
        )


def check_room(state: AppState, tenant: str, adding: int, *, written: bool = False) -> None:
    """Free space and the tenant's quota (counted by the storage) for ``adding`` more bytes,
    which are ``written`` to disk already or not yet (blocking: call it on a thread)."""
    check_free_space(state.settings, 0 if written else adding)
    used = state.storage.tenant_bytes(state.store, tenant)
    check_quota(state.settings, used, adding)


def tree_bytes(folder: Path) -> int:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file() and not p.is_symlink())


def prepare(archive: Path, dest: Path, settings: Settings) -> tuple[dict[str, Any], int]:
    """Extract and validate (see :func:`extract_and_validate`); also the bytes extracted."""
    summary = extract_and_validate(archive, dest, settings)
    return summary, tree_bytes(dest)


# ----- the validation pool -----


class ValidationPool:
    """Runs extraction and validation on threads of their own, and admits a bounded number
    of uploads.

    At most ``workers`` validations run at once (an anyio ``CapacityLimiter``, first come first
    served, apart from the default threadpool the sync routes and ``run_in_threadpool`` use).
    At most ``pending`` uploads are admitted at a time (receiving, waiting or validating); one
    more answers 503 with ``Retry-After`` before its body is read. Used on the event loop only.
    """

    def __init__(self, workers: int, pending: int, retry_after_s: int) -> None:
        self.limiter = anyio.CapacityLimiter(workers)
        self.pending = pending
        self.retry_after_s = retry_after_s
        self.admitted = 0

    @contextmanager
    def admit(self) -> Iterator[None]:
        if self.admitted >= self.pending:
            raise ApiProblem(
                503,
                f"{self.admitted} uploads are being received or validated, the most this "
                "server takes at once; try again later",
                slug="too-many-uploads",
                headers={"Retry-After": str(self.retry_after_s)},
            )
        self.admitted += 1
        try:
            yield
        finally:
            self.admitted -= 1

    async def run(self, func: Callable[..., T], *args: Any) -> T:
        """``func(*args)`` on a pool thread; waits for it even when the request is cancelled
        (its temporary folder is removed only after the thread stopped writing)."""
        return await anyio.to_thread.run_sync(func, *args, limiter=self.limiter)


def validation_pool(app_state: Any, settings: Settings) -> ValidationPool:
    """The app's pool (``app.state.upload_pool``), made on first use inside the event loop."""
    pool: ValidationPool | None = getattr(app_state, "upload_pool", None)
    if pool is None:
        pool = ValidationPool(
            settings.max_upload_validations, settings.max_pending_uploads, settings.retry_after_s
        )
        app_state.upload_pool = pool
    return pool


# ----- expiry -----


def remove_expired_uploads(store: Store, settings: Settings, storage: Storage) -> list[str]:
    """Delete uploads no job refers to that are older than ``upload_expiry_s``; their ids.

    An upload some job uses (finished or not) is kept; one a job is created for at the same
    moment either stays (the job came first) or the job answers 404 (the row lock and the
    job's foreign key decide).
    """
    if not settings.upload_expiry_s:
        return []
    cutoff = utcnow() - timedelta(seconds=settings.upload_expiry_s)
    removed: list[str] = []
    for upload_id in store.unused_uploads(cutoff):
        try:
            upload = store.delete_upload(upload_id, None)
        except UploadInUse:
            continue
        if upload is not None:
            storage.remove_upload(upload.tenant_id, upload_id)
            removed.append(upload_id)
    if removed:
        logger.info("removed %d expired upload(s): %s", len(removed), removed)
    return removed
