"""``.npy`` maps and the errors a damaged ``.npy`` / ``.npz`` raises, for precise messages.

:func:`numpy.load` parses an ``.npy`` header (a Python dict literal) with :mod:`tokenize` and
:func:`ast.literal_eval`, so a damaged header raises :class:`tokenize.TokenError` or
:class:`SyntaxError` besides the ``OSError`` / ``ValueError`` / ``EOFError`` of a short or
unreadable file; an ``.npz`` adds :class:`zipfile.BadZipFile`. A header may also claim any shape:
:func:`read_npy_map` checks it against :data:`~dcseg.io.images.MAX_PIXELS` and the current pixel
budget before numpy allocates the array.
"""

from __future__ import annotations

import tokenize
import zipfile
from pathlib import Path
from typing import IO, Any

import numpy as np
from numpy.lib import format as npy_format
from numpy.typing import NDArray

from dcseg.errors import InputError
from dcseg.io.images import MAX_PIXELS, charge_pixels

__all__ = ["NUMPY_FILE_ERRORS", "npy_file_header", "npy_header", "read_npy_map"]

NUMPY_FILE_ERRORS: tuple[type[Exception], ...] = (
    OSError,
    ValueError,
    EOFError,
    SyntaxError,
    tokenize.TokenError,
    zipfile.BadZipFile,
)
"""What reading a damaged ``.npy`` or ``.npz`` with numpy raises (module docstring)."""


def read_npy_map(path: Path, shown: str) -> NDArray[Any]:
    """The array of an ``.npy`` file holding a label or class map, its header checked first
    (callers check that it is 2D and of an integer type).

    Raises:
        InputError: naming ``shown``: an unreadable or damaged file, or more elements than
            :data:`~dcseg.io.images.MAX_PIXELS` or the current pixel budget allows.
    """
    try:
        shape, _ = npy_file_header(path)
    except NUMPY_FILE_ERRORS as err:
        raise InputError.single(shown, f"cannot read .npy array: {err}") from err
    size = int(np.prod(shape, dtype=np.int64))
    if size > MAX_PIXELS:
        reason = f"array of shape {shape} is above the limit of {MAX_PIXELS:,} pixels"
        raise InputError.single(shown, reason)
    charge_pixels(size, shown)
    try:
        return np.asarray(np.load(path, allow_pickle=False))
    except NUMPY_FILE_ERRORS as err:
        raise InputError.single(shown, f"cannot read .npy array: {err}") from err


def npy_header(handle: IO[bytes]) -> tuple[tuple[int, ...], np.dtype[Any]]:
    """Shape and dtype from the ``.npy`` header at ``handle``'s position (format 1.0, 2.0 or
    3.0; an ``.npz`` member works too), nothing else read."""
    version = npy_format.read_magic(handle)
    read = (
        npy_format.read_array_header_1_0 if version == (1, 0) else npy_format.read_array_header_2_0
    )
    shape, _, dtype = read(handle)
    return tuple(int(v) for v in shape), np.dtype(dtype)


def npy_file_header(path: Path) -> tuple[tuple[int, ...], np.dtype[Any]]:
    """:func:`npy_header` of an ``.npy`` file."""
    with path.open("rb") as handle:
        return npy_header(handle)
