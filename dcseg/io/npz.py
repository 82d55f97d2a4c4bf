"""Arrays of an uncompressed ``.npz`` read straight from their place in the file.

:func:`numpy.load` reads an ``.npz`` member through :mod:`zipfile`, which checksums it and hands
its bytes over in chunks that numpy copies into the array: a view of the blend-weight cache
(12 MB at 320x240, 50 MB at 640x480) costs twice what reading it takes. The members
:func:`numpy.savez` writes are stored, not compressed, so each array's bytes sit contiguously
after its zip and ``.npy`` headers: :func:`read_stored` finds them with :mod:`zipfile`'s own
directory, parses the ``.npy`` header with :mod:`numpy.lib.format` and reads the data with one
:func:`numpy.fromfile`. It checks each array's length against its header (a truncated file is
an error), not its checksum: it is meant for caches a run wrote itself.
"""

from __future__ import annotations

import struct
import zipfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
from numpy.lib import format as npy_format
from numpy.typing import NDArray

_LOCAL_HEADER = 30
"""Bytes of a zip local file header before its name and extra field."""


def read_stored(path: Path, names: Sequence[str]) -> dict[str, NDArray[Any]] | None:
    """The arrays ``names`` of the ``.npz`` at ``path`` that it holds (absent ones are left
    out), or None when one of them is compressed (then :func:`numpy.load` must read it).

    Members in a ``.npy`` format version other than 1.0 and 2.0 also give None.

    Raises:
        ValueError: the file is not a zip, or a member's header or length is wrong.
        OSError: the file cannot be read.
    """
    try:
        with zipfile.ZipFile(path) as archive:
            members = {i.filename.removesuffix(".npy"): i for i in archive.infolist()}
    except zipfile.BadZipFile as error:
        raise ValueError(str(error)) from None
    wanted = [members[n] for n in names if n in members]
    if any(m.compress_type != zipfile.ZIP_STORED for m in wanted):
        return None
    with path.open("rb") as handle:
        try:
            return {m.filename.removesuffix(".npy"): _member(handle, m) for m in wanted}
        except _Unsupported:
            return None


class _Unsupported(Exception):
    """A member in a ``.npy`` version this reader leaves to :func:`numpy.load`."""


def _member(handle: BinaryIO, member: zipfile.ZipInfo) -> NDArray[Any]:
    handle.seek(member.header_offset)
    header = handle.read(_LOCAL_HEADER)
    if len(header) != _LOCAL_HEADER or header[:4] != b"PK\x03\x04":
        raise ValueError(f"{member.filename}: bad zip member header")
    name_length, extra_length = struct.unpack("<HH", header[26:30])
    handle.seek(member.header_offset + _LOCAL_HEADER + name_length + extra_length)
    version = npy_format.read_magic(handle)
    readers = {
        (1, 0): npy_format.read_array_header_1_0,
        (2, 0): npy_format.read_array_header_2_0,
    }
    if version not in readers:
        raise _Unsupported(version)
    shape, fortran_order, dtype = readers[version](handle)
    if dtype.hasobject:
        raise ValueError(f"{member.filename}: object arrays are not read")
    count = int(np.prod(shape, dtype=np.int64))
    data = np.fromfile(handle, dtype=dtype, count=count)
    if data.size != count:
        raise ValueError(f"{member.filename}: {data.size} of {count} values present")
    return data.reshape(shape, order="F" if fortran_order else "C")
