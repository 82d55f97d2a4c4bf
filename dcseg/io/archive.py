"""Safe extraction of uploaded ``.zip`` and ``.tar`` (``.gz``, ``.bz2``, ``.xz``) archives.

Archives are untrusted input (the HTTP service extracts uploads with :func:`safe_extract`), so:

* every entry name is checked before anything is written: absolute paths, drive letters and
  ``..`` components are refused, as are symlinks, hard links, devices and FIFOs;
* the number of entries is capped, and the total size is capped on the bytes actually written
  (sizes in headers can lie);
* tar members also go through the standard library's ``"data"`` extraction filter.

macOS resource folders (``__MACOSX/``) are skipped. Every entry is checked before the first file
is written, but a size cap or a corrupt stream can stop extraction midway: after a failure
``dest`` may hold the files extracted so far, so callers extract into a temporary folder.
"""

from __future__ import annotations

import logging
import stat
import tarfile
import zipfile
import zlib
from collections.abc import Iterator
from pathlib import Path, PurePosixPath
from typing import IO

from dcseg.errors import InputError

__all__ = ["ARCHIVE_SUFFIXES", "is_archive", "safe_extract"]

logger = logging.getLogger(__name__)

ARCHIVE_SUFFIXES = (".zip", ".tar", ".tar.gz", ".tgz", ".tar.bz2", ".tar.xz")
"""File name endings :func:`is_archive` recognises."""

_CHUNK = 1 << 20
_SKIPPED_TOP = frozenset({"__MACOSX"})
_CORRUPT = (tarfile.TarError, zipfile.BadZipFile, zlib.error, EOFError, OSError)


def is_archive(path: Path) -> bool:
    """Whether ``path`` names an archive by its suffix (``.zip``, ``.tar``, ``.tar.gz``...)."""
    return path.name.lower().endswith(ARCHIVE_SUFFIXES)


class _Budget:
    """Counts entries and bytes written against the caps."""

    def __init__(self, archive: Path, max_entries: int, max_total_bytes: int) -> None:
        self.archive = archive
        self.max_entries = max_entries
        self.max_total_bytes = max_total_bytes
        self.written = 0
        self.tops: dict[str, bool] = {}  # top-level name -> whether it is a folder

    def note(self, dest: Path, target: Path, is_dir: bool) -> None:
        """Remember the top-level entry ``target`` belongs to."""
        parts = target.relative_to(dest).parts
        self.tops[parts[0]] = self.tops.get(parts[0], False) or is_dir or len(parts) > 1

    def check_count(self, count: int) -> None:
        if count > self.max_entries:
            raise InputError.single(
                str(self.archive), f"archive has more than {self.max_entries:,} entries"
            )

    def add(self, name: str, nbytes: int) -> None:
        self.written += nbytes
        if self.written > self.max_total_bytes:
            raise InputError.single(
                str(self.archive),
                f"archive expands to more than {self.max_total_bytes:,} bytes "
                f"(limit reached while extracting entry {name!r})",
            )


def _entry_parts(name: str) -> tuple[str, ...]:
    """The path components of an entry, or raise if the entry could leave the folder."""
    normal = name.replace("\\", "/")
    pure = PurePosixPath(normal)
    drive = len(normal) >= 2 and normal[1] == ":"
    if pure.is_absolute() or drive:
        raise _escape(name, "is an absolute path")
    parts = tuple(p for p in pure.parts if p not in ("", "."))
    if ".." in parts:
        raise _escape(name, "escapes the archive folder")
    return parts


class _UnsafeEntry(Exception):
    """An entry that must not be extracted; turned into an InputError naming the archive."""


def _escape(name: str, why: str) -> _UnsafeEntry:
    return _UnsafeEntry(f"archive entry {name!r} {why}")


def _target(dest: Path, name: str) -> Path | None:
    """Where entry ``name`` goes under ``dest``, or None when it is skipped."""
    parts = _entry_parts(name)
    if not parts or parts[0] in _SKIPPED_TOP:
        return None
    target = dest.joinpath(*parts)
    if not target.resolve().is_relative_to(dest.resolve()):
        raise _escape(name, "escapes the archive folder")
    return target


def _copy(source: IO[bytes], target: Path, name: str, budget: _Budget) -> None:
    target.parent.mkdir(parents=True, exist_ok=True)
    with target.open("wb") as out:
        while chunk := source.read(_CHUNK):
            budget.add(name, len(chunk))
            out.write(chunk)


def _zip_kind(info: zipfile.ZipInfo) -> str:
    kind = stat.S_IFMT(info.external_attr >> 16)  # 0 when the zip stores no Unix file type
    if info.is_dir() or kind == stat.S_IFDIR:
        return "dir"
    if kind in (0, stat.S_IFREG):
        return "file"
    return "link" if kind == stat.S_IFLNK else "special file"


def _check_zip(zf: zipfile.ZipFile, dest: Path, budget: _Budget) -> None:
    infos = zf.infolist()
    budget.check_count(len(infos))
    for info in infos:
        _target(dest, info.filename)
        kind = _zip_kind(info)
        if kind not in ("dir", "file"):
            raise _escape(info.filename, f"is a {kind}, which is not allowed")
        if info.flag_bits & 0x1:
            raise _escape(info.filename, "is encrypted")
    declared = sum(i.file_size for i in infos)
    if declared > budget.max_total_bytes:
        raise InputError.single(
            str(budget.archive),
            f"archive expands to {declared:,} bytes, above the limit of "
            f"{budget.max_total_bytes:,} bytes",
        )


def _extract_zip(archive: Path, dest: Path, budget: _Budget) -> None:
    with zipfile.ZipFile(archive) as zf:
        _check_zip(zf, dest, budget)
        for info in zf.infolist():
            target = _target(dest, info.filename)
            if target is None:
                continue
            budget.note(dest, target, info.is_dir())
            if info.is_dir():
                target.mkdir(parents=True, exist_ok=True)
                continue
            with zf.open(info) as source:
                _copy(source, target, info.filename, budget)


def _tar_members(tf: tarfile.TarFile, budget: _Budget) -> Iterator[tarfile.TarInfo]:
    count = 0
    while (member := tf.next()) is not None:
        count += 1
        budget.check_count(count)
        yield member


def _check_tar_member(member: tarfile.TarInfo, dest: Path) -> None:
    _target(dest, member.name)
    if member.issym() or member.islnk():
        raise _escape(member.name, "is a link, which is not allowed")
    if not (member.isfile() or member.isdir()):
        raise _escape(member.name, "is a device or special file, which is not allowed")
    try:
        tarfile.data_filter(member, str(dest))
    except tarfile.FilterError as exc:
        raise _escape(member.name, f"is refused by the tar data filter ({exc})") from None


def _extract_tar(archive: Path, dest: Path, budget: _Budget) -> None:
    with tarfile.open(archive, "r:*") as tf:
        members = list(_tar_members(tf, budget))
        for member in members:
            _check_tar_member(member, dest)
        for member in members:
            target = _target(dest, member.name)
            if target is None:
                continue
            budget.note(dest, target, member.isdir())
            if member.isdir():
                target.mkdir(parents=True, exist_ok=True)
                continue
            source = tf.extractfile(member)
            if source is None:  # pragma: no cover - regular files always have data
                continue
            with source:
                _copy(source, target, member.name, budget)


def _single_top_folder(dest: Path, budget: _Budget) -> Path:
    if len(budget.tops) == 1:
        name, is_dir = next(iter(budget.tops.items()))
        if is_dir:
            return dest / name
    return dest


def safe_extract(
    archive: Path,
    dest: Path,
    *,
    max_entries: int = 100_000,
    max_total_bytes: int = 20 * 2**30,
) -> Path:
    """Extract an untrusted ``.zip`` or ``.tar[.gz|.bz2|.xz]`` archive into ``dest``.

    Args:
        archive: the archive file (the format is detected from its content).
        dest: the folder to extract into; created if missing.
        max_entries: refuse archives with more entries than this.
        max_total_bytes: stop and refuse once more than this many bytes have been written.

    Returns:
        The archive's single top-level folder if it has exactly one, else ``dest``.

    Raises:
        InputError: an entry is unsafe (absolute, ``..``, link, device), a cap is exceeded,
            or the file is corrupt or not a supported archive.

    Example:
        >>> root = safe_extract(Path("scan.zip"), Path(tmp))  # doctest: +SKIP
    """
    budget = _Budget(archive, max_entries, max_total_bytes)
    dest.mkdir(parents=True, exist_ok=True)
    try:
        if zipfile.is_zipfile(archive):
            _extract_zip(archive, dest, budget)
        elif tarfile.is_tarfile(archive):
            _extract_tar(archive, dest, budget)
        else:
            raise InputError.single(
                str(archive), "not a supported archive (expected .zip, .tar, .tar.gz or .tgz)"
            )
    except _UnsafeEntry as exc:
        raise InputError.single(str(archive), str(exc)) from None
    except FileNotFoundError:
        raise InputError.single(str(archive), "missing") from None
    except (*_CORRUPT, RuntimeError, NotImplementedError) as exc:
        raise InputError.single(str(archive), f"corrupt or unreadable archive ({exc})") from None
    logger.debug("extracted %s into %s (%d bytes)", archive, dest, budget.written)
    return _single_top_folder(dest, budget)
