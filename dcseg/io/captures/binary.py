"""Little-endian binary files read field by field (COLMAP models, ScanNet ``.sens``).

Every read names the file, the field and the byte offset when the file is cut short, and counts
are checked against the bytes left before anything is allocated for them.
"""

from __future__ import annotations

import struct
from pathlib import Path
from typing import Any, BinaryIO

from dcseg.errors import InputError

__all__ = ["BinaryReader", "open_binary"]


def open_binary(path: Path, shown: str) -> tuple[BinaryIO, int]:
    """The open file and its size, or an InputError naming ``shown``."""
    try:
        return path.open("rb"), path.stat().st_size
    except OSError as exc:
        raise InputError.single(shown, f"cannot read file ({exc.strerror})") from None


class BinaryReader:
    """Little-endian reads that name the file, the field and the byte offset when cut short."""

    def __init__(self, handle: BinaryIO, size: int, shown: str) -> None:
        self.handle, self.size, self.shown = handle, size, shown

    @property
    def left(self) -> int:
        """Bytes after the current position."""
        return self.size - self.handle.tell()

    def take(self, fmt: str, field: str) -> tuple[Any, ...]:
        """``struct.unpack("<" + fmt)`` of the next bytes."""
        need = struct.calcsize("<" + fmt)
        at = self.handle.tell()
        data = self.handle.read(need)
        if len(data) < need:
            raise self.truncated(at, field, need)
        return struct.unpack("<" + fmt, data)

    def read(self, need: int, field: str) -> bytes:
        """The next ``need`` bytes (checked against the file size before reading)."""
        at = self.handle.tell()
        if need > self.left:
            raise self.truncated(at, field, need)
        return self.handle.read(need)

    def skip(self, need: int, field: str) -> None:
        """Move past ``need`` bytes."""
        if need > self.left:
            raise self.truncated(self.handle.tell(), field, need)
        self.handle.seek(need, 1)

    def name(self, field: str) -> str:
        """A NUL-terminated UTF-8 string."""
        at, raw = self.handle.tell(), bytearray()
        while (byte := self.handle.read(1)) != b"\x00":
            if not byte:
                raise InputError.single(
                    self.shown, f"truncated at byte {at}: {field} ends before its NUL terminator"
                )
            raw += byte
        try:
            return raw.decode("utf-8")
        except UnicodeDecodeError:
            raise InputError.single(self.shown, f"byte {at}: {field} is not UTF-8") from None

    def count(self, item: str, smallest: int) -> int:
        """A ``uint64`` count of items of at least ``smallest`` bytes each, checked against the
        bytes left."""
        (value,) = self.take("Q", f"the number of {item}s")
        count = int(value)
        if count * smallest > self.left:
            raise InputError.single(
                self.shown,
                f"truncated: declares {count} {item}s but only {self.left} bytes follow "
                f"(each takes at least {smallest})",
            )
        return count

    def truncated(self, at: int, field: str, need: int) -> InputError:
        """The error of a field cut short."""
        return InputError.single(
            self.shown,
            f"truncated at byte {at}: {field} needs {need} bytes, {self.size - at} left",
        )
