"""Image files: decoding with clear errors, encoding, and resampling.

Every reader in :mod:`dcseg.io` decodes images through :func:`read_image`, so that an unreadable,
corrupt or oversized file always produces an :class:`~dcseg.errors.InputError` naming the file.
Colour images come back as RGB(A); single-channel images (depth, label maps) keep their dtype.

Sizes are read from PNG, JPEG and TIFF headers before anything is decoded, both for the per-image
limit :data:`MAX_PIXELS` and for an optional total budget: inside ``with pixel_budget(n):``
every decode is charged against ``n`` pixels (by its header before decoding, or, for formats
whose header is not read, by its decoded size), and a decode beyond the budget is refused.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from dcseg.errors import InputError
from dcseg.io.limits import limit_error

__all__ = [
    "MAX_PIXELS",
    "charge_pixels",
    "display_path",
    "header_pixels",
    "image_size",
    "pixel_budget",
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
_TIFF_BYTE_ORDER = {b"II*\x00": "<", b"MM\x00*": ">"}
_TIFF_WIDTH, _TIFF_LENGTH = 256, 257
_TIFF_SHORT, _TIFF_LONG = 3, 4
_HEADER_BYTES = 65536


class _PixelBudget:
    """Pixels decoded so far against a total limit."""

    def __init__(self, limit: int) -> None:
        self.limit = limit
        self.used = 0


_BUDGET: ContextVar[_PixelBudget | None] = ContextVar("dcseg_pixel_budget", default=None)


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


def _tiff_size(head: bytes, read_at: Callable[[int, int], bytes]) -> tuple[int, int] | None:
    """Width and length tags of a classic TIFF's first IFD; ``read_at(offset, n)`` reads bytes."""
    order = _TIFF_BYTE_ORDER.get(head[:4])
    if order is None or len(head) < 8:
        return None
    (ifd,) = struct.unpack(order + "I", head[4:8])
    count_bytes = read_at(ifd, 2)
    if len(count_bytes) < 2:
        return None
    (count,) = struct.unpack(order + "H", count_bytes)
    entries = read_at(ifd + 2, 12 * count)
    found: dict[int, int] = {}
    for i in range(len(entries) // 12):
        tag, kind, _, value = struct.unpack(order + "HHI4s", entries[12 * i : 12 * i + 12])
        if tag in (_TIFF_WIDTH, _TIFF_LENGTH) and kind in (_TIFF_SHORT, _TIFF_LONG):
            fmt = "H" if kind == _TIFF_SHORT else "I"
            found[tag] = int(struct.unpack_from(order + fmt, value)[0])
    if _TIFF_WIDTH not in found or _TIFF_LENGTH not in found:
        return None
    return found[_TIFF_WIDTH], found[_TIFF_LENGTH]


def _header_size(data: bytes) -> tuple[int, int] | None:
    """The size of a PNG, JPEG or TIFF held (at least its header) in ``data``."""
    return (
        _png_size(data)
        or _jpeg_size(data)
        or _tiff_size(data, lambda offset, n: data[offset : offset + n])
    )


def image_size(path: Path) -> tuple[int, int] | None:
    """``(width, height)`` of a PNG, JPEG or TIFF read from its header only; None otherwise.

    Args:
        path: the image file.

    Returns:
        The size, or None for other formats or unreadable headers.
    """
    try:
        with path.open("rb") as fh:
            head = fh.read(_HEADER_BYTES)

            def read_at(offset: int, n: int) -> bytes:
                fh.seek(offset)
                return fh.read(n)

            return _png_size(head) or _jpeg_size(head) or _tiff_size(head, read_at)
    except OSError:
        return None


def header_pixels(path: Path) -> int | None:
    """How many pixels (or ``.npy`` values) decoding ``path`` gives, read from its header only.

    Args:
        path: a PNG, JPEG, TIFF, OpenEXR or ``.npy`` file, or a video (one frame's pixels:
            validation counts it once per frame it reads).

    Returns:
        ``width * height`` (the element count for ``.npy``), or None when the header is not
        one of those formats or cannot be read.
    """
    if path.suffix.lower() == ".npy":
        try:
            return int(np.load(path, mmap_mode="r", allow_pickle=False).size)
        except (OSError, ValueError, EOFError):
            return None
    from dcseg.io.video import VIDEO_SUFFIXES, video_size  # both readers import this module

    if path.suffix.lower() == ".exr":
        from dcseg.io.exr import exr_size

        size = exr_size(path)
    elif path.suffix.lower() in VIDEO_SUFFIXES:
        size = video_size(path)  # one frame's pixels
    else:
        size = image_size(path)
    return None if size is None else size[0] * size[1]


@contextmanager
def pixel_budget(max_pixels: int | None) -> Iterator[None]:
    """Within the block, refuse decodes once more than ``max_pixels`` pixels were decoded.

    Args:
        max_pixels: the total budget; None = no budget.
    """
    token = _BUDGET.set(None if max_pixels is None else _PixelBudget(max_pixels))
    try:
        yield
    finally:
        _BUDGET.reset(token)


def charge_pixels(pixels: int, shown: str) -> None:
    """Count ``pixels`` against the current :func:`pixel_budget`, if any.

    Raises:
        InputError: (a :class:`~dcseg.io.limits.LimitProblem`) the budget is exceeded.
    """
    budget = _BUDGET.get()
    if budget is None:
        return
    budget.used += pixels
    if budget.used > budget.limit:
        raise limit_error(
            shown,
            f"not decoded: the inputs decode to more than {budget.limit:,} pixels in total",
            "max_pixels",
        )


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
        InputError: the file is missing, empty, not an image, corrupt, larger than
            :data:`MAX_PIXELS`, or beyond the current :func:`pixel_budget`.
    """
    shown = display_path(path, root)
    data = _read_bytes(path, shown)
    header = _header_size(data)
    _check_pixels(header, shown)
    if header is not None:
        charge_pixels(header[0] * header[1], shown)
    image = _decode(data, shown)
    _check_pixels((int(image.shape[1]), int(image.shape[0])), shown)
    if header is None:
        charge_pixels(int(image.shape[0]) * int(image.shape[1]), shown)
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
