"""Safe extraction of uploaded ``.zip``, ``.tar`` and ``.tar.gz`` archives.

Archives are untrusted input (the HTTP service extracts uploads with :func:`safe_extract`), so:

* every entry name is checked before it is written: absolute paths, drive letters, ``..``
  components and names that are not valid UTF-8 are refused, as are symlinks, hard links,
  devices and FIFOs;
* a zip's entry count and central-directory size are read from its end-of-central-directory
  record (ZIP64 included) before the directory itself is read;
* tar members are read one header at a time: the entry count, each member's declared size and
  the total declared size are checked as each header arrives, and pax / GNU long-name header
  records are capped, so limits apply before the rest of the stream is decompressed;
* the total size is also capped on the bytes actually written (sizes in headers can lie);
* tar members also go through the standard library's ``"data"`` extraction filter;
* only uncompressed and gzip-compressed tar are accepted (bzip2, xz and other compressions are
  refused by their magic bytes).

macOS resource folders (``__MACOSX/``) are skipped. Every zip entry is checked before the first
file is written; tar members are checked one by one as they are extracted. A cap or a corrupt
stream can therefore stop extraction midway: after a failure ``dest`` may hold the files
extracted so far, so callers extract into a temporary folder.
"""

from __future__ import annotations

import gzip
import io
import logging
import stat
import struct
import tarfile
import zipfile
import zlib
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import IO

from dcseg.errors import InputError
from dcseg.io.limits import limit_error

__all__ = ["ARCHIVE_SUFFIXES", "is_archive", "safe_extract"]

logger = logging.getLogger(__name__)

ARCHIVE_SUFFIXES = (".zip", ".tar", ".tar.gz", ".tgz")
"""File name endings :func:`is_archive` recognises."""

_CHUNK = 1 << 20
_SKIPPED_TOP = frozenset({"__MACOSX"})
_CORRUPT = (tarfile.TarError, zipfile.BadZipFile, zlib.error, EOFError, OSError)
_UNSUPPORTED_MAGIC = {
    b"BZh": "bzip2",
    b"\xfd7zXZ\x00": "xz",
    b"\x28\xb5\x2f\xfd": "zstd",
    b"\x5d\x00\x00": "lzma",
    b"7z\xbc\xaf\x27\x1c": "7z",
    b"Rar!": "rar",
}
_GZIP_MAGIC = b"\x1f\x8b"

# Zip end-of-central-directory records (APPNOTE.TXT 4.3.14-4.3.16).
_EOCD = struct.Struct("<4s4H2LH")
_EOCD_SIG = b"PK\x05\x06"
_ZIP64_LOCATOR = struct.Struct("<4sLQL")
_ZIP64_LOCATOR_SIG = b"PK\x06\x07"
_ZIP64_EOCD = struct.Struct("<4sQ2H2L4Q")
_ZIP64_EOCD_SIG = b"PK\x06\x06"
_MAX_COMMENT = 0xFFFF


def is_archive(path: Path) -> bool:
    """Whether ``path`` names an archive by its suffix (``.zip``, ``.tar``, ``.tar.gz``...)."""
    return path.name.lower().endswith(ARCHIVE_SUFFIXES)


@dataclass(frozen=True)
class _Limits:
    max_entries: int
    max_total_bytes: int
    max_directory_bytes: int
    max_header_bytes: int


class _Budget:
    """Counts entries and bytes (declared and written) against the caps."""

    def __init__(self, archive: Path, limits: _Limits) -> None:
        self.archive = archive
        self.limits = limits
        self.written = 0
        self.declared = 0
        self.tops: dict[str, bool] = {}  # top-level name -> whether it is a folder

    def note(self, dest: Path, target: Path, is_dir: bool) -> None:
        """Remember the top-level entry ``target`` belongs to."""
        parts = target.relative_to(dest).parts
        self.tops[parts[0]] = self.tops.get(parts[0], False) or is_dir or len(parts) > 1

    def check_count(self, count: int) -> None:
        if count > self.limits.max_entries:
            raise limit_error(
                str(self.archive),
                f"archive has more than {self.limits.max_entries:,} entries",
                "max_entries",
            )

    def declare(self, name: str, nbytes: int) -> None:
        """Add an entry's declared size; refuse once the declared total is over the cap."""
        self.declared += nbytes
        if self.declared > self.limits.max_total_bytes:
            raise self._too_big(
                f"entry {_shown(name)} declares {nbytes:,} bytes, "
                f"{self.declared:,} bytes declared so far"
            )

    def add(self, name: str, nbytes: int) -> None:
        self.written += nbytes
        if self.written > self.limits.max_total_bytes:
            raise self._too_big(f"limit reached while extracting entry {_shown(name)}")

    def _too_big(self, why: str) -> InputError:
        return limit_error(
            str(self.archive),
            f"archive expands to more than {self.limits.max_total_bytes:,} bytes ({why})",
            "max_total_bytes",
        )


def _shown(name: str) -> str:
    """An entry name for messages: quoted, bytes that are not valid UTF-8 shown as ``\\xNN``."""
    raw = name.encode("utf-8", "surrogateescape")
    return "'" + raw.decode("utf-8", "backslashreplace") + "'"


def _entry_parts(name: str) -> tuple[str, ...]:
    """The path components of an entry, or raise if the entry could leave the folder."""
    try:
        name.encode("utf-8")
    except UnicodeEncodeError:
        raise _escape(name, "has a name that is not valid UTF-8") from None
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
    return _UnsafeEntry(f"archive entry {_shown(name)} {why}")


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
    chunk = min(_CHUNK, budget.limits.max_header_bytes)
    with target.open("wb") as out:
        while data := source.read(chunk):
            budget.add(name, len(data))
            out.write(data)


# --------------------------------------------------------------------------- zip


@dataclass(frozen=True)
class _ZipDirectory:
    """What a zip's end-of-central-directory record says about its central directory."""

    entries: int
    size: int


def _read_tail(fh: IO[bytes], file_size: int) -> tuple[bytes, int]:
    """The last bytes of the file that can hold the EOCD record, and their offset."""
    start = max(0, file_size - _EOCD.size - _MAX_COMMENT)
    fh.seek(start)
    return fh.read(), start


def _find_eocd(tail: bytes) -> int | None:
    """Position in ``tail`` of the EOCD record whose comment runs exactly to the end."""
    pos = tail.rfind(_EOCD_SIG)
    while pos >= 0:
        if pos + _EOCD.size <= len(tail):
            comment = _EOCD.unpack_from(tail, pos)[7]
            if pos + _EOCD.size + comment == len(tail):
                return pos
        pos = tail.rfind(_EOCD_SIG, 0, pos)
    return None


def _zip64_directory(fh: IO[bytes], locator_at: int) -> _ZipDirectory:
    """Entry count and directory size from the ZIP64 EOCD record the locator points to."""
    fh.seek(locator_at)
    _, _, offset, _ = _ZIP64_LOCATOR.unpack(fh.read(_ZIP64_LOCATOR.size))
    for at in (offset, locator_at - _ZIP64_EOCD.size):  # absolute, or just before (prefixed)
        if at < 0:
            continue
        fh.seek(at)
        record = fh.read(_ZIP64_EOCD.size)
        if len(record) == _ZIP64_EOCD.size and record.startswith(_ZIP64_EOCD_SIG):
            fields = _ZIP64_EOCD.unpack(record)
            return _ZipDirectory(entries=int(fields[7]), size=int(fields[8]))
    raise zipfile.BadZipFile("ZIP64 end of central directory record not found")


def _zip_directory(archive: Path) -> _ZipDirectory | None:
    """The central directory's entry count and size from the end records, or None (not a zip).

    Reads at most the last 64 KiB (+ the ZIP64 records), never the directory itself.
    """
    with archive.open("rb") as fh:
        file_size = fh.seek(0, 2)
        tail, start = _read_tail(fh, file_size)
        pos = _find_eocd(tail)
        if pos is None:
            return None
        fields = _EOCD.unpack_from(tail, pos)
        locator_at = start + pos - _ZIP64_LOCATOR.size
        if locator_at >= 0:
            fh.seek(locator_at)
            if fh.read(4) == _ZIP64_LOCATOR_SIG:
                return _zip64_directory(fh, locator_at)
        return _ZipDirectory(entries=int(fields[4]), size=int(fields[5]))


def _check_zip_directory(directory: _ZipDirectory, budget: _Budget) -> None:
    budget.check_count(directory.entries)
    limit = budget.limits.max_directory_bytes
    if directory.size > limit:
        raise limit_error(
            str(budget.archive),
            f"zip central directory is {directory.size:,} bytes, above the limit of {limit:,} "
            "bytes",
            "max_directory_bytes",
        )


def _zip_kind(info: zipfile.ZipInfo) -> str:
    kind = stat.S_IFMT(info.external_attr >> 16)  # 0 when the zip stores no Unix file type
    if info.is_dir() or kind == stat.S_IFDIR:
        return "dir"
    if kind in (0, stat.S_IFREG):
        return "file"
    return "link" if kind == stat.S_IFLNK else "special file"


def _check_zip(zf: zipfile.ZipFile, dest: Path, budget: _Budget) -> None:
    infos = zf.infolist()
    budget.check_count(len(infos))  # the EOCD count can lie; the directory cannot
    for info in infos:
        _target(dest, info.filename)
        kind = _zip_kind(info)
        if kind not in ("dir", "file"):
            raise _escape(info.filename, f"is a {kind}, which is not allowed")
        if info.flag_bits & 0x1:
            raise _escape(info.filename, "is encrypted")
    declared = sum(i.file_size for i in infos)
    if declared > budget.limits.max_total_bytes:
        raise limit_error(
            str(budget.archive),
            f"archive expands to {declared:,} bytes, above the limit of "
            f"{budget.limits.max_total_bytes:,} bytes",
            "max_total_bytes",
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


# --------------------------------------------------------------------------- tar


class _HeaderTooLarge(Exception):
    """tarfile asked for a read larger than the header cap."""

    def __init__(self, nbytes: int) -> None:
        super().__init__(nbytes)
        self.nbytes = nbytes


class _CappedReads:
    """A file wrapper refusing any single read larger than ``limit`` bytes.

    tarfile reads a pax or GNU long-name header record in one read of its declared size, so
    this stops a huge record before it is allocated. Member data is read in smaller chunks.
    """

    def __init__(self, raw: io.BufferedIOBase, limit: int) -> None:
        self.raw = raw
        self.limit = limit

    def read(self, size: int = -1) -> bytes:
        if size < 0 or size > self.limit:
            raise _HeaderTooLarge(size)
        return self.raw.read(size)

    def seek(self, offset: int, whence: int = 0) -> int:
        return self.raw.seek(offset, whence)

    def tell(self) -> int:
        return self.raw.tell()


def _compression(archive: Path) -> str | None:
    """``"gzip"``, None (no compression) or the name of a refused compression."""
    with archive.open("rb") as fh:
        head = fh.read(8)
    if head.startswith(_GZIP_MAGIC):
        return "gzip"
    for magic, name in _UNSUPPORTED_MAGIC.items():
        if head.startswith(magic):
            raise InputError.single(
                str(archive),
                f"{name}-compressed archives are not supported "
                "(use .zip, .tar or gzip-compressed .tar.gz / .tgz)",
            )
    return None


@contextmanager
def _open_tar(archive: Path, compression: str | None, budget: _Budget) -> Iterator[tarfile.TarFile]:
    """The tar file, decompressed on the fly, with reads capped at the header limit."""
    raw: io.BufferedIOBase = (
        gzip.GzipFile(archive, "rb") if compression == "gzip" else archive.open("rb")
    )
    with raw:
        capped = _CappedReads(raw, budget.limits.max_header_bytes)
        try:
            tf = tarfile.open(fileobj=capped, mode="r:")  # type: ignore[call-overload]
        except tarfile.ReadError:
            raise InputError.single(str(archive), _NOT_SUPPORTED) from None
        with tf:
            yield tf


def _tar_members(tf: tarfile.TarFile, budget: _Budget) -> Iterator[tarfile.TarInfo]:
    """Members one header at a time, each counted and its declared size checked."""
    count = 0
    while (member := tf.next()) is not None:
        count += 1
        budget.check_count(count)
        if member.isfile():
            budget.declare(member.name, member.size)
        yield member


_DATA_FILTER = getattr(tarfile, "data_filter", None)
"""The standard library's tar data filter (PEP 706): Python 3.12, and 3.11 from 3.11.4 (Debian
bookworm's 3.11.2 has none); a second check behind ours, which extraction never skips."""


def _check_tar_member(member: tarfile.TarInfo, dest: Path) -> None:
    _target(dest, member.name)
    if member.issym() or member.islnk():
        raise _escape(member.name, "is a link, which is not allowed")
    if not (member.isfile() or member.isdir()):
        raise _escape(member.name, "is a device or special file, which is not allowed")
    if _DATA_FILTER is None:
        return  # the checks above cover what the filter refuses (names, links, specials)
    try:
        _DATA_FILTER(member, str(dest))
    except tarfile.FilterError as exc:
        raise _escape(member.name, f"is refused by the tar data filter ({exc})") from None


def _extract_tar_member(
    tf: tarfile.TarFile, member: tarfile.TarInfo, dest: Path, budget: _Budget
) -> None:
    _check_tar_member(member, dest)
    target = _target(dest, member.name)
    if target is None:
        return
    budget.note(dest, target, member.isdir())
    if member.isdir():
        target.mkdir(parents=True, exist_ok=True)
        return
    source = tf.extractfile(member)
    if source is None:  # pragma: no cover - regular files always have data
        return
    with source:
        _copy(source, target, member.name, budget)


def _extract_tar(archive: Path, compression: str | None, dest: Path, budget: _Budget) -> None:
    try:
        with _open_tar(archive, compression, budget) as tf:
            for member in _tar_members(tf, budget):
                _extract_tar_member(tf, member, dest, budget)
    except _HeaderTooLarge as exc:
        limit = budget.limits.max_header_bytes
        raise limit_error(
            str(archive),
            f"archive has a tar header record (pax or GNU long name) of {exc.nbytes:,} bytes, "
            f"above the limit of {limit:,} bytes",
            "max_header_bytes",
        ) from None


# --------------------------------------------------------------------------- entry point

_NOT_SUPPORTED = "not a supported archive (expected .zip, .tar, .tar.gz or .tgz)"


def _single_top_folder(dest: Path, budget: _Budget) -> Path:
    if len(budget.tops) == 1:
        name, is_dir = next(iter(budget.tops.items()))
        if is_dir:
            return dest / name
    return dest


def _extract(archive: Path, dest: Path, budget: _Budget) -> None:
    directory = _zip_directory(archive)
    if directory is not None:
        _check_zip_directory(directory, budget)
        _extract_zip(archive, dest, budget)
        return
    _extract_tar(archive, _compression(archive), dest, budget)


def safe_extract(
    archive: Path,
    dest: Path,
    *,
    max_entries: int = 100_000,
    max_total_bytes: int = 20 * 2**30,
    max_directory_bytes: int = 64 * 2**20,
    max_header_bytes: int = 2**20,
) -> Path:
    """Extract an untrusted ``.zip``, ``.tar`` or ``.tar.gz`` archive into ``dest``.

    Args:
        archive: the archive file (the format is detected from its content).
        dest: the folder to extract into; created if missing.
        max_entries: refuse archives with more entries than this (a zip's count is read from
            its end record before its central directory is read).
        max_total_bytes: refuse archives whose entries declare more bytes than this, and stop
            once more than this many bytes have been written.
        max_directory_bytes: refuse zips whose central directory is larger than this.
        max_header_bytes: refuse tars with a pax or GNU long-name header record larger than
            this (at least 512; file data is read in chunks of at most this size).

    Returns:
        The archive's single top-level folder if it has exactly one, else ``dest``.

    Raises:
        InputError: an entry is unsafe (absolute, ``..``, link, device, not UTF-8), a cap is
            exceeded (the problem is a :class:`~dcseg.io.limits.LimitProblem` naming the
            argument), or the file is corrupt or not a supported archive.

    Example:
        >>> root = safe_extract(Path("scan.zip"), Path(tmp))  # doctest: +SKIP
    """
    if max_header_bytes < tarfile.BLOCKSIZE:
        raise ValueError(f"max_header_bytes must be at least {tarfile.BLOCKSIZE}")
    limits = _Limits(max_entries, max_total_bytes, max_directory_bytes, max_header_bytes)
    budget = _Budget(archive, limits)
    dest.mkdir(parents=True, exist_ok=True)
    try:
        _extract(archive, dest, budget)
    except _UnsafeEntry as exc:
        raise InputError.single(str(archive), str(exc)) from None
    except FileNotFoundError:
        raise InputError.single(str(archive), "missing") from None
    except (*_CORRUPT, RuntimeError, NotImplementedError, UnicodeDecodeError) as exc:
        raise InputError.single(str(archive), f"corrupt or unreadable archive ({exc})") from None
    logger.debug("extracted %s into %s (%d bytes)", archive, dest, budget.written)
    return _single_top_folder(dest, budget)
