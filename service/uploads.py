"""Receiving an upload: stream to disk under a size cap, check the digest, extract, validate.

Everything happens in ``uploads/.tmp-<id>/``, renamed to ``uploads/<id>/`` only once the
upload is valid, so a failed upload leaves nothing behind.
"""

from __future__ import annotations

import base64
import binascii
import hashlib
import re
import shutil
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

from fastapi.concurrency import run_in_threadpool

from service.problems import ApiProblem
from service.settings import Settings
from worker.contract import input_digests, input_layout

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
                await run_in_threadpool(out.write, bytes(buffer))
                buffer.clear()
        if buffer:
            await run_in_threadpool(out.write, bytes(buffer))
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
    from dcseg.io.archive import safe_extract
    from dcseg.io.validate import InputPaths, validate_inputs

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
    report = validate_inputs(InputPaths(**layout), max_pixels=settings.max_validation_pixels)
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
