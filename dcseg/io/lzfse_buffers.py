"""Bounded decoding of LZFSE-compressed raw buffers (Record3D's ``.depth`` and ``.conf`` files).

The ``lzfse`` package's ``decompress`` grows its output buffer until the stream fits, so a small
crafted file could expand to gigabytes. Here the reference decoder that the same package
compiles (``lzfse_decode_buffer``) writes into a buffer of exactly the size the capture's
metadata implies, plus one byte: a stream that fills the extra byte decodes to more than
expected and is refused, without ever allocating more. Implied sizes above
:data:`dcseg.io.limits.MAX_DECOMPRESSED_BYTES` are refused before anything is read.
"""

from __future__ import annotations

import ctypes
from pathlib import Path
from typing import Any

import lzfse
import numpy as np
from numpy.typing import NDArray

from dcseg.errors import InputError
from dcseg.io import images, limits
from dcseg.io.limits import limit_error

__all__ = ["compress", "read_lzfse_array"]

_LIB = ctypes.CDLL(lzfse.__file__)
_DECODE = _LIB.lzfse_decode_buffer
_DECODE.restype = ctypes.c_size_t
_DECODE.argtypes = [
    ctypes.c_void_p,
    ctypes.c_size_t,
    ctypes.c_void_p,
    ctypes.c_size_t,
    ctypes.c_void_p,
]
_MAX_OVERHEAD = 4096
"""How many bytes a compressed file may exceed its decoded size by (block headers of an
incompressible stream stored raw)."""


def compress(data: bytes) -> bytes:
    """LZFSE-compress ``data`` (what Record3D writes; used to write captures and fixtures)."""
    return bytes(lzfse.compress(data))


def _read_compressed(path: Path, shown: str, expected: int) -> bytes:
    try:
        size = path.stat().st_size
    except FileNotFoundError:
        raise InputError.single(shown, "missing") from None
    except OSError as exc:
        raise InputError.single(shown, f"cannot read file ({exc.strerror})") from None
    if size == 0:
        raise InputError.single(shown, "file is empty (expected LZFSE-compressed data)")
    if size > expected + _MAX_OVERHEAD:
        raise InputError.single(
            shown,
            f"compressed file has {size:,} bytes, more than its decoded size of {expected:,} "
            "bytes can need (corrupt, or not this frame's buffer)",
        )
    try:
        return path.read_bytes()
    except OSError as exc:
        raise InputError.single(shown, f"cannot read file ({exc.strerror})") from None


def read_lzfse_array(
    path: Path, shown: str, size: tuple[int, int], dtype: type[np.generic]
) -> NDArray[Any]:
    """An LZFSE-compressed raw ``[H, W]`` array of ``dtype`` (little-endian, row-major).

    Args:
        path: the compressed file.
        shown: how messages name the file.
        size: ``(width, height)`` the metadata states for the buffer.
        dtype: the element type (``np.float32`` depth, ``np.uint8`` confidence).

    Returns:
        The decoded ``[height, width]`` array.

    Raises:
        InputError: the file is missing, empty, corrupt, or decodes to another size than
            ``width * height * itemsize`` bytes; a :class:`~dcseg.io.limits.LimitProblem`
            when that size is above :data:`~dcseg.io.limits.MAX_DECOMPRESSED_BYTES` or the
            current pixel budget.
    """
    width, height = size
    itemsize = np.dtype(dtype).itemsize
    expected = width * height * itemsize
    if expected > limits.MAX_DECOMPRESSED_BYTES:
        raise limit_error(
            shown,
            f"a {width}x{height} buffer of {np.dtype(dtype).name} is {expected:,} bytes, above "
            f"the limit of {limits.MAX_DECOMPRESSED_BYTES:,} bytes; nothing was decoded",
            "max_decompressed_bytes",
        )
    images.charge_pixels(width * height, shown)
    data = _read_compressed(path, shown, expected)
    out = bytearray(expected + 1)
    target = (ctypes.c_char * len(out)).from_buffer(out)
    written = int(_DECODE(target, len(out), data, len(data), None))
    del target
    if written == 0:
        raise InputError.single(shown, "cannot decompress (corrupt or not LZFSE data)")
    if written != expected:
        more = "more than" if written > expected else f"{written:,} bytes, not"
        raise InputError.single(
            shown,
            f"decompresses to {more} the {expected:,} bytes of a {width}x{height} "
            f"{np.dtype(dtype).name} buffer stated by the metadata",
        )
    array = np.frombuffer(out, dtype=np.dtype(dtype).newbyteorder("<"), count=width * height)
    return array.reshape(height, width).astype(dtype)
