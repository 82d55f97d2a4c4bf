"""Local files of the client: archives it uploads, and where and how downloads are written."""

from __future__ import annotations

import hashlib
import tarfile
from collections.abc import Iterator
from pathlib import Path, PurePosixPath
from typing import Any

from dcseg.client.errors import ClientError

__all__ = ["ARCHIVE_TYPES", "file_chunks", "pack_folder", "ready_target", "sha256_of", "verified"]

ARCHIVE_TYPES = {
    ".zip": "application/zip",
    ".tar": "application/x-tar",
    ".tgz": "application/gzip",
    ".gz": "application/gzip",
}
"""Content types of the archives the service accepts, by file suffix."""


def file_chunks(path: Path, size: int = 1 << 20) -> Iterator[bytes]:
    with path.open("rb") as handle:
        while chunk := handle.read(size):
            yield chunk


def sha256_of(path: Path) -> str:
    digest = hashlib.sha256()
    for chunk in file_chunks(path):
        digest.update(chunk)
    return digest.hexdigest()


def verified(path: Path, item: dict[str, Any]) -> bool:
    """Whether ``path`` holds the listed file (its size, when listed, then its SHA-256)."""
    size = item.get("size")
    if not path.is_file() or (size is not None and path.stat().st_size != size):
        return False
    return sha256_of(path) == str(item["sha256"])


def ready_target(item: dict[str, Any], dest: Path) -> tuple[Path, Path]:
    """Where the listed file goes under ``dest``, and its ``.part`` file (folders made);
    ClientError for a name that would leave ``dest``."""
    relative = PurePosixPath(item["name"])
    if relative.is_absolute() or ".." in relative.parts:
        raise ClientError(f"the service listed an unsafe file name {item['name']!r}")
    target = dest.joinpath(*relative.parts)
    target.parent.mkdir(parents=True, exist_ok=True)
    return target, target.with_name(target.name + ".part")


def pack_folder(folder: Path, archive: Path) -> Path:
    """Write ``folder``'s contents (not the folder itself: its files are at the archive's
    root, as ``tar -C folder -cf archive .`` does) into the tar ``archive``, file by file
    (nothing is held in memory); symbolic links are stored as the files they point to."""
    with tarfile.open(archive, "w", dereference=True) as tar:
        for path in sorted(folder.rglob("*")):
            tar.add(path, arcname=path.relative_to(folder).as_posix(), recursive=False)
    return archive
