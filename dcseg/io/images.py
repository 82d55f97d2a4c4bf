"""Image files: decoding with clear errors, encoding, and resampling.

Every reader in :mod:`dcseg.io` decodes images through :func:`read_image`, so that an unreadable,
corrupt or oversized file always produces an :class:`~dcseg.errors.InputError` naming the file.
Colour images come back as RGB(A); single-channel images (depth, label maps) keep their dtype.
"""

from __future__ import annotations

import struct
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from dcseg.errors import InputError

__all__ = [
    "MAX_PIXELS",
    "display_path",
    "image_size",
    "read_image",
    "resize_area",
    "resize_nearest",
    "write_image",
    "write_png",
]

MAX_PIXELS = 100_000_000
"""Largest image (width x height) that :func:`read_image` agrees to decode."""

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_JPEG_SOF = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}


def display_path(path: Path, root: Path | None = None) -> str:
    """``path`` relative to ``root`` when it lies inside it, else ``path`` as given."""
    if root is not None:
        try:
            return path.relative_to(root).as_posix()
        except ValueError:
            pass
    return str(path)


def _png_size(data: bytes) -> tuple[int, int] | None:
    if len(data) < 24 or not data.startswith(_PNG_SIGNATURE) or data[12:16] != b"IHDR":
        return None
    width, height = struct.unpack(">II", data[16:24])
    return int(width), int(height)


def _jpeg_size(data: bytes) -> tuple[int, int] | None:
    if not data.startswith(b"\xff\xd8"):
        return None
    pos = 2
    while pos + 9 <= len(data):
        if data[pos] != 0xFF:
            return None
        marker = data[pos + 1]
        if marker == 0xFF:  # fill byte
            pos += 1
            continue
        if marker in _JPEG_SOF:
            height, width = struct.unpack(">HH", data[pos + 5 : pos + 9])
            return int(width), int(height)
        if marker == 0x01 or 0xD0 <= marker <= 0xD9:  # markers without a length field
            pos += 2
            continue
        (length,) = struct.unpack(">H", data[pos + 2 : pos + 4])
        pos += 2 + length
    return None


def _header_size(data: bytes) -> tuple[int, int] | None:
    return _png_size(data) or _jpeg_size(data)


def image_size(path: Path) -> tuple[int, int] | None:
    """``(width, height)`` of a PNG or JPEG read from its header only; None if not recognised.

    Args:
        path: the image file.

    Returns:
        The size, or None for other formats or unreadable headers.
    """
    try:
        with path.open("rb") as fh:
            data = fh.read(65536)
    except OSError:
        return None
    return _header_size(data)


def _read_bytes(path: Path, shown: str) -> bytes:
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise InputError.single(shown, "missing") from None
    except IsADirectoryError:
        raise InputError.single(shown, "is a folder, expected an image file") from None
    except OSError as exc:
        raise InputError.single(shown, f"cannot read file ({exc.strerror})") from None
    if not data:
        raise InputError.single(shown, "file is empty (expected an image)")
    return data


def _check_pixels(size: tuple[int, int] | None, shown: str) -> None:
    if size is not None and size[0] * size[1] > MAX_PIXELS:
        raise InputError.single(
            shown,
            f"image is {size[0]}x{size[1]} pixels, above the limit of {MAX_PIXELS:,} pixels",
        )


def _decode(data: bytes, shown: str) -> NDArray[Any]:
    try:
        image = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    except cv2.error:
        image = None
    if image is None or image.size == 0:
        raise InputError.single(shown, "cannot decode image (corrupt or not an image)")
    return np.asarray(image)


def read_image(path: Path, *, root: Path | None = None) -> NDArray[Any]:
    """Decode an image file as stored (``IMREAD_UNCHANGED``), colour converted to RGB(A).

    Args:
        path: the image file.
        root: when given, messages name ``path`` relative to it.

    Returns:
        ``[H, W]`` for single-channel images (dtype as stored, e.g. uint16 depth),
        ``[H, W, 3]`` RGB or ``[H, W, 4]`` RGBA for colour images.

    Raises:
        InputError: the file is missing, empty, not an image, corrupt, or larger than
            :data:`MAX_PIXELS`.
    """
    shown = display_path(path, root)
    data = _read_bytes(path, shown)
    _check_pixels(_header_size(data), shown)
    image = _decode(data, shown)
    _check_pixels((int(image.shape[1]), int(image.shape[0])), shown)
    if image.ndim == 3 and image.shape[2] == 3:
        return np.ascontiguousarray(image[:, :, ::-1])
    if image.ndim == 3 and image.shape[2] == 4:
        return cv2.cvtColor(image, cv2.COLOR_BGRA2RGBA)
    if image.ndim == 3 and image.shape[2] == 1:
        return np.ascontiguousarray(image[:, :, 0])
    return image


def write_image(path: Path, image: NDArray[Any]) -> Path:
    """Encode ``image`` to ``path``; the format follows the suffix (``.png``, ``.jpg``...).

    Args:
        path: destination file; parent folders are created.
        image: ``[H, W]`` (any cv2-supported dtype) or ``[H, W, 3]`` RGB / ``[H, W, 4]`` RGBA.

    Returns:
        ``path``.

    Raises:
        ValueError: the array cannot be encoded in that format.
    """
    array = np.asarray(image)
    if array.ndim == 3 and array.shape[2] == 3:
        array = np.ascontiguousarray(array[:, :, ::-1])
    elif array.ndim == 3 and array.shape[2] == 4:
        array = cv2.cvtColor(array, cv2.COLOR_RGBA2BGRA)
    ok, buffer = cv2.imencode(path.suffix or ".png", array)
    if not ok:
        raise ValueError(f"cannot encode a {array.shape} {array.dtype} array as {path.suffix}")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(buffer.tobytes())
    return path


def write_png(path: Path, image: NDArray[Any]) -> Path:
    """Write ``image`` losslessly as PNG (uint8 or uint16; RGB colour).

    Returns:
        The written path (``path`` with its suffix replaced by ``.png`` if it had another).
    """
    return write_image(path.with_suffix(".png") if path.suffix != ".png" else path, image)


def resize_area(image: NDArray[Any], size: tuple[int, int]) -> NDArray[Any]:
    """Resample a colour image to ``size = (width, height)`` with the area filter."""
    if (image.shape[1], image.shape[0]) == size:
        return image
    return np.asarray(cv2.resize(image, size, interpolation=cv2.INTER_AREA))


def resize_nearest(image: NDArray[Any], size: tuple[int, int]) -> NDArray[Any]:
    """Resample depth or labels to ``size = (width, height)`` with nearest neighbour.

    Works for any dtype and uses the pixel-centre convention of
    :meth:`dcseg.types.Intrinsics.scaled`: output pixel ``i`` takes input pixel
    ``floor((i + 0.5) * in / out)``.
    """
    height, width = int(image.shape[0]), int(image.shape[1])
    if (width, height) == size:
        return image
    cols = _nearest_index(width, size[0])
    rows = _nearest_index(height, size[1])
    return np.ascontiguousarray(image[rows[:, None], cols[None, :]])


def _nearest_index(n_in: int, n_out: int) -> NDArray[np.int64]:
    index: NDArray[np.int64] = np.floor((np.arange(n_out) + 0.5) * (n_in / n_out)).astype(np.int64)
    return np.minimum(index, n_in - 1, out=index)
