"""Serving a job's artifacts: the manifest decides what exists (no path from the URL is
trusted), downloads carry a strong ETag (the SHA-256) and answer single ``Range`` requests."""

from __future__ import annotations

import mimetypes
import re
from dataclasses import dataclass
from pathlib import PurePosixPath

from jobstore.blobstore import Storage, StoredFile
from service.problems import ApiProblem

MEDIA_TYPES = {
    ".ply": "application/octet-stream",
    ".json": "application/json",
    ".npz": "application/octet-stream",
    ".npy": "application/octet-stream",
    ".txt": "text/plain",
    ".png": "image/png",
    ".glb": "model/gltf-binary",
    ".obj": "model/obj",
    ".spz": "application/octet-stream",
    ".splat": "application/octet-stream",
    ".usdz": "model/vnd.usdz+zip",
}
_RANGE = re.compile(r"^bytes=(\d*)-(\d*)$", re.IGNORECASE)


@dataclass(frozen=True)
class Artifact:
    """A file of a finished stage, as the API serves it."""

    item: StoredFile

    @property
    def name(self) -> str:
        return self.item.name

    @property
    def size(self) -> int:
        return self.item.size

    @property
    def sha256(self) -> str:
        return self.item.sha256

    @property
    def media_type(self) -> str:
        suffix = PurePosixPath(self.name).suffix.lower()
        guessed = MEDIA_TYPES.get(suffix) or mimetypes.guess_type(self.name)[0]
        return guessed or "application/octet-stream"

    @property
    def etag(self) -> str:
        return f'"{self.sha256}"'


def list_artifacts(storage: Storage, tenant: str, job_id: str) -> list[Artifact]:
    """Every file of every finished stage, in stage order."""
    return [Artifact(item) for item in storage.files(tenant, job_id)]


def find_artifact(storage: Storage, tenant: str, job_id: str, name: str) -> Artifact | None:
    return next((a for a in list_artifacts(storage, tenant, job_id) if a.name == name), None)


def parse_range(header: str | None, size: int) -> tuple[int, int] | None:
    """``(start, end)`` inclusive for a single satisfiable byte range; None = whole file.

    The unit ``bytes`` is case-insensitive (RFC 9110 14.1). Several ranges, another unit or an
    invalid range (last before first) are ignored (whole file, as RFC 9110 allows); a valid but
    unsatisfiable range answers 416. Positions are compared as digit strings, never converted
    unbounded, so a number of any length is handled (beyond the file it is clamped).
    """
    if header is None:
        return None
    match = _RANGE.match(header.strip().replace(" ", ""))
    if match is None:
        return None
    first, last = (_digits(group) for group in match.groups())
    if first is None and last is None:
        return None
    if first is None:
        length = _clamped(last or "0", size)
        if length == 0 or size == 0:
            raise unsatisfiable(size)
        return size - length, size - 1
    if last is not None and _less(last, first):
        return None
    start = _clamped(first, size)
    if start >= size:
        raise unsatisfiable(size)
    end = size - 1 if last is None else min(_clamped(last, size), size - 1)
    return start, end


def _digits(text: str) -> str | None:
    """A position without leading zeros (``"0"`` for zero); None when absent."""
    if not text:
        return None
    return text.lstrip("0") or "0"


def _less(a: str, b: str) -> bool:
    """``int(a) < int(b)`` for digit strings without leading zeros, of any length."""
    return (len(a), a) < (len(b), b)


def _clamped(digits: str, cap: int) -> int:
    """``min(int(digits), cap)`` without converting more digits than ``cap`` has."""
    if len(digits) > len(str(cap)):
        return cap
    return min(int(digits), cap)


def unsatisfiable(size: int) -> ApiProblem:
    return ApiProblem(
        416,
        f"the range lies beyond the end of the file ({size} bytes)",
        slug="range-not-satisfiable",
        headers={"Content-Range": f"bytes */{size}"},
    )
