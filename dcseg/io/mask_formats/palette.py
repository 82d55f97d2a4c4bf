"""Palette PNGs (colour type 3: DAVIS, SAM2's video predictor, DEVA, Pascal VOC) as index maps.

These tools store one index per pixel and a colour table. A PNG decoder (OpenCV included)
returns the colours, which say nothing once two tables differ, so the indices are read instead:
the file's ``PLTE`` chunk is swapped for the identity table (entry ``i`` = grey ``i``) before
decoding, and the grey value of a pixel is then its index. No other PNG library is needed, and
every bit depth the format allows (1, 2, 4, 8) is handled by libpng itself.
"""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from dcseg.errors import InputError
from dcseg.io.images import MAX_PIXELS, charge_pixels, display_path

__all__ = ["PALETTE_VOID", "is_palette_png", "read_palette_indices"]

PALETTE_VOID = 255
"""Pascal VOC's index for object boundaries and "difficult" pixels: ignored by both readers."""

_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_IHDR_END = 8 + 8 + 13 + 4
_COLOUR_TYPE_PALETTE = 3
_DROPPED_CHUNKS = (b"PLTE", b"tRNS", b"hIST", b"bKGD")
"""Chunks that refer to palette entries: replaced (PLTE) or left out (the rest)."""


def is_palette_png(path: Path) -> bool:
    """Whether ``path`` is a PNG whose header says colour type 3 (indexed colour)."""
    try:
        with path.open("rb") as handle:
            head = handle.read(_IHDR_END)
    except OSError:
        return False
    return _is_palette_header(head)


def _is_palette_header(head: bytes) -> bool:
    return (
        len(head) >= 26
        and head.startswith(_SIGNATURE)
        and head[12:16] == b"IHDR"
        and head[25] == _COLOUR_TYPE_PALETTE
    )


def read_palette_indices(path: Path, *, root: Path | None = None) -> NDArray[np.uint8]:
    """The palette index of every pixel of an indexed-colour PNG.

    Args:
        path: the PNG file.
        root: when given, messages name ``path`` relative to it.

    Returns:
        ``[H, W]`` uint8 indices.

    Raises:
        InputError: the file cannot be read, is not a palette PNG, is corrupt, is larger than
            :data:`~dcseg.io.images.MAX_PIXELS` or beyond the current pixel budget.
    """
    import cv2

    shown = display_path(path, root)
    try:
        data = path.read_bytes()
    except OSError as err:
        raise InputError.single(shown, f"cannot read file ({err.strerror})") from None
    if not _is_palette_header(data[:_IHDR_END]):
        raise InputError.single(shown, "not a palette PNG (colour type 3)")
    width, height, bit_depth = struct.unpack(">IIB", data[16:25])
    if width * height > MAX_PIXELS:
        reason = f"image is {width}x{height} pixels, above the limit of {MAX_PIXELS:,} pixels"
        raise InputError.single(shown, reason)
    charge_pixels(width * height, shown)
    try:
        grey = _with_identity_palette(data, bit_depth)
        image = cv2.imdecode(np.frombuffer(grey, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    except (ValueError, cv2.error):
        image = None
    if image is None or image.shape[:2] != (height, width):
        raise InputError.single(shown, "cannot decode palette PNG (corrupt file)")
    indices: NDArray[np.uint8] = np.ascontiguousarray(image[..., 0] if image.ndim == 3 else image)
    return indices


def _with_identity_palette(data: bytes, bit_depth: int) -> bytes:
    """The same PNG with ``PLTE`` = the identity greys and no chunk that indexes the palette.

    Raises:
        ValueError: a chunk runs past the end of the file.
    """
    entries = 1 << min(bit_depth, 8)
    palette = bytes(np.repeat(np.arange(entries, dtype=np.uint8), 3))
    out = [data[:_IHDR_END], _chunk(b"PLTE", palette)]
    at = _IHDR_END
    while at + 8 <= len(data):
        (length,) = struct.unpack(">I", data[at : at + 4])
        kind = data[at + 4 : at + 8]
        end = at + 12 + length
        if end > len(data):
            raise ValueError("truncated chunk")
        if kind not in _DROPPED_CHUNKS:
            out.append(data[at:end])
        at = end
    return b"".join(out)


def _chunk(kind: bytes, body: bytes) -> bytes:
    crc = zlib.crc32(kind + body) & 0xFFFFFFFF
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", crc)
