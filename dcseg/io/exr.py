"""OpenEXR depth images (Record3D's "EXR + JPG" export), read with the OpenEXR bindings.

The header is read first: an image above :data:`dcseg.io.images.MAX_PIXELS`, or beyond the
current pixel budget, is refused before any pixel is decoded, as for PNG and JPEG.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import OpenEXR
from numpy.typing import NDArray

from dcseg.errors import InputError
from dcseg.io import images

__all__ = ["DEPTH_CHANNELS", "exr_size", "read_exr_depth"]

DEPTH_CHANNELS = ("R", "Y", "Z", "depth")
"""Channel names holding depth, in order of preference (an image with one channel uses it)."""


def _header(path: Path, shown: str) -> dict[str, Any]:
    if not path.is_file():
        raise InputError.single(shown, "missing")
    try:
        with OpenEXR.File(str(path), header_only=True) as exr:
            return dict(exr.header())
    except (RuntimeError, ValueError, OSError):
        raise InputError.single(
            shown, "cannot read EXR header (corrupt or not an EXR image)"
        ) from None


def exr_size(path: Path) -> tuple[int, int] | None:
    """``(width, height)`` of an EXR image from its header, or None when unreadable."""
    try:
        return _window_size(_header(path, str(path)))
    except InputError:
        return None


def _window_size(header: dict[str, Any]) -> tuple[int, int]:
    low, high = (np.asarray(v, dtype=np.int64) for v in header["dataWindow"])
    return int(high[0] - low[0] + 1), int(high[1] - low[1] + 1)


def _channel(names: list[str], shown: str) -> str:
    for name in DEPTH_CHANNELS:
        if name in names:
            return name
    if len(names) == 1:
        return names[0]
    raise InputError.single(
        shown, f"no depth channel: expected one of {', '.join(DEPTH_CHANNELS)}, got {names}"
    )


def read_exr_depth(path: Path, shown: str) -> NDArray[np.float32]:
    """A single-channel EXR depth image as ``[H, W]`` float32 metres (NaN/inf/negative = 0).

    Raises:
        InputError: missing, corrupt, no depth channel, above the pixel limit or budget.
    """
    header = _header(path, shown)
    width, height = _window_size(header)
    if width < 1 or height < 1 or width * height > images.MAX_PIXELS:
        raise InputError.single(
            shown,
            f"image is {width}x{height} pixels, outside 1 to {images.MAX_PIXELS:,} pixels",
        )
    images.charge_pixels(width * height, shown)
    names = [str(channel.name) for channel in header["channels"]]
    channel = _channel(names, shown)
    try:
        with OpenEXR.File(str(path)) as exr:
            pixels = np.asarray(exr.channels()[channel].pixels)
    except (RuntimeError, ValueError, OSError, KeyError):
        raise InputError.single(shown, "cannot decode EXR image (corrupt)") from None
    if pixels.shape != (height, width):
        raise InputError.single(
            shown, f"depth must be one {width}x{height} channel, got shape {pixels.shape}"
        )
    metres = pixels.astype(np.float32)
    return np.where(np.isfinite(metres) & (metres > 0), metres, np.float32(0.0))
