"""Opening a PLY file someone else wrote: its header's element counts checked against the file's
size before plyfile allocates them, and every parse failure named.

plyfile allocates each element's array from the count its header declares before reading a
row, so a header of a few bytes declaring 10^11 vertices asks for terabytes; an ASCII value
beyond its declared type raises ``OverflowError``. :func:`open_ply` refuses a count the rest of
the file cannot hold (each row of a binary element takes at least the bytes of its scalar
properties, each row of an ASCII element at least two characters per property) and turns what
plyfile raises into an :class:`~dcseg.errors.InputError` naming the file.
"""

from __future__ import annotations

from pathlib import Path

from plyfile import PlyData

from dcseg.errors import InputError

__all__ = ["open_ply"]

_HEADER_LIMIT = 1 << 20
"""Bytes searched for ``end_header``."""

_SIZES = {
    "char": 1, "uchar": 1, "int8": 1, "uint8": 1, "short": 2, "ushort": 2, "int16": 2,
    "uint16": 2, "int": 4, "uint": 4, "int32": 4, "uint32": 4, "float": 4, "float32": 4,
    "double": 8, "float64": 8,
}  # fmt: skip
"""Bytes of each PLY scalar type (both spellings of the specification)."""


def open_ply(path: Path, shown: str, *, mmap: bool = False) -> PlyData:
    """The parsed PLY at ``path`` (binary elements memory-mapped copy-on-write with ``mmap``).

    Raises:
        InputError: naming ``shown``: missing or unreadable, no PLY header, an element count
            the file is too short to hold, or any failure of plyfile's parser.
    """
    try:
        size = path.stat().st_size
        with path.open("rb") as handle:
            head = handle.read(_HEADER_LIMIT)
    except FileNotFoundError:
        raise InputError.single(shown, "file not found") from None
    except OSError as err:
        raise InputError.single(shown, f"cannot read file ({err.strerror})") from None
    reason = _count_problem(head, size)
    if reason:
        raise InputError.single(shown, f"not a readable PLY file: {reason}")
    try:
        return PlyData.read(str(path), mmap="c" if mmap else False)
    except Exception as err:  # plyfile raises many types (ValueError, IndexError, Overflow...)
        raise InputError.single(shown, f"not a readable PLY file ({err})") from None


def _count_problem(head: bytes, size: int) -> str:
    """Why the header's element counts cannot be right for a file of ``size`` bytes, or ""
    (also "" when the header cannot be parsed here: plyfile then names what is wrong)."""
    end = head.find(b"end_header")
    if end < 0:
        return ""
    body = size - (head.find(b"\n", end) + 1)
    lines = head[:end].decode("ascii", errors="replace").splitlines()
    text = any(line.split()[:2] == ["format", "ascii"] for line in lines)
    needed, element, row = 0, None, 0
    for words in (line.split() for line in lines):
        if words[:1] == ["element"] and len(words) == 3 and words[2].isdigit():
            needed += _bytes(element, row)
            element, row = (words[1], int(words[2])), 0
        elif words[:1] == ["property"] and len(words) >= 3:
            kind = words[2] if words[1] == "list" else words[1]
            row += 2 if text else _SIZES.get(kind, 1)
    needed += _bytes(element, row)
    if needed > body:
        return f"its header declares rows of at least {needed:,} bytes, the file holds {body:,}"
    return ""


def _bytes(element: tuple[str, int] | None, row: int) -> int:
    return 0 if element is None else element[1] * max(row, 1)
