"""Serving a job's artifacts: the manifest decides what exists (no path from the URL is
trusted), downloads carry a strong ETag (the SHA-256) and answer single ``Range`` requests."""

from __future__ import annotations

import json
import mimetypes
import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from service.problems import ApiProblem

CHUNK = 1 << 20
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
}
_RANGE = re.compile(r"^bytes=(\d*)-(\d*)$", re.IGNORECASE)


@dataclass(frozen=True)
class Artifact:
    name: str
    path: Path
    size: int
    sha256: str

    @property
    def media_type(self) -> str:
        suffix = self.path.suffix.lower()
        guessed = MEDIA_TYPES.get(suffix) or mimetypes.guess_type(self.path.name)[0]
        return guessed or "application/octet-stream"

    @property
    def etag(self) -> str:
        return f'"{self.sha256}"'


def read_manifest(output: Path) -> dict[str, Any]:
    try:
        data: dict[str, Any] = json.loads((output / "manifest.json").read_text(encoding="utf-8"))
    except (FileNotFoundError, json.JSONDecodeError):
        return {"stages": []}
    return data


def list_artifacts(output: Path) -> list[Artifact]:
    """Every file of every finished stage, in stage order."""
    found: list[Artifact] = []
    root = output.resolve()
    for stage in read_manifest(output).get("stages", []):
        for name, info in sorted(stage.get("files", {}).items()):
            path = (root / name).resolve()
            if path.is_relative_to(root) and path.is_file():
                found.append(Artifact(name, path, int(info["size"]), str(info["sha256"])))
    return found


def find_artifact(output: Path, name: str) -> Artifact | None:
    return next((a for a in list_artifacts(output) if a.name == name), None)


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


def read_bytes(path: Path, start: int, end: int) -> Iterator[bytes]:
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
