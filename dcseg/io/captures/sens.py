"""Raw ScanNet ``.sens`` files, decoded into ScanNet's export layout (read by :mod:`.scannet`).

A ``.sens`` file is given like an archive: :func:`dcseg.io.captures.list_capture` decodes it
into a temporary folder (``color/<i>.jpg``, ``depth/<i>.png``, ``pose/<i>.txt``,
``intrinsic/intrinsic_color.txt`` and ``intrinsic_depth.txt``, what ScanNet's ``SensReader``
exports) and lists that folder; the layout is ``scannet-sens``. Colour bytes are copied as
they are (no re-encoding); depth is decompressed and written as 16-bit PNG.

Byte layout (ScanNet's ``SensReader/python/SensorData.py``, version 4, little-endian)::

    uint32 version (4), uint64 n + n bytes sensor name,
    float32[16] intrinsic_color, extrinsic_color, intrinsic_depth, extrinsic_depth (row-major),
    int32 colour compression (0 raw, 1 png, 2 jpeg), int32 depth compression (0 raw_ushort,
    1 zlib_ushort, 2 occi_ushort), uint32 colour width, height, depth width, height,
    float32 depth shift (stored value / shift = metres), uint64 frame count, then per frame:
    float32[16] camera-to-world, uint64 colour and depth timestamps, uint64 colour and depth
    byte counts, the colour bytes, the depth bytes.

Colour must be JPEG or PNG and depth raw or zlib uint16 with a shift of 1000 (ScanNet's); other
values are refused naming the field. Every count is checked against the file size before
anything is read for it, each depth frame decompresses into exactly ``width * height * 2``
bytes (more is refused without allocating it), and the decoded files may not exceed
``max_total_bytes``.
"""

from __future__ import annotations

import logging
import zlib
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from dcseg.errors import InputError
from dcseg.io.captures.binary import BinaryReader, open_binary
from dcseg.io.images import write_image
from dcseg.io.limits import MAX_DECOMPRESSED_BYTES, limit_error

__all__ = ["MAX_TOTAL_BYTES", "SENS_SUFFIX", "extract"]

logger = logging.getLogger(__name__)

SENS_SUFFIX = ".sens"
MAX_TOTAL_BYTES = 20 * 2**30
"""Largest total size of the files a ``.sens`` is decoded into (the archive default)."""

_VERSION = 4
_COLOUR = {1: ".png", 2: ".jpg"}
_COLOUR_NAMES = {-1: "unknown", 0: "raw", 1: "png", 2: "jpeg"}
_DEPTH_NAMES = {-1: "unknown", 0: "raw_ushort", 1: "zlib_ushort", 2: "occi_ushort"}
_DEPTH_SHIFT = 1000.0
_FRAME_HEADER = 16 * 4 + 4 * 8


def extract(path: Path, dest: Path, max_total_bytes: int = MAX_TOTAL_BYTES) -> Path:
    """Decode a ``.sens`` file into ScanNet's export layout under ``dest``.

    Returns:
        ``dest``, holding ``color/``, ``depth/``, ``pose/`` and ``intrinsic/``.

    Raises:
        InputError: naming the file and the field (and byte offset) at fault.
    """
    shown = str(path)
    handle, size = open_binary(path, shown)
    with handle:
        data = BinaryReader(handle, size, shown)
        header = _Header.read(data)
        header.write(dest)
        count = data.count("frame", _FRAME_HEADER)
        written = 0
        for index in range(count):
            written += _frame(data, header, index, dest)
            if written > max_total_bytes:
                raise limit_error(
                    shown,
                    f"decoded frames exceed {max_total_bytes:,} bytes after frame {index}",
                    "max_total_bytes",
                )
    logger.info("decoded %d frames of %s (%d bytes)", count, shown, written)
    return dest


class _Header:
    """The header fields dcseg uses."""

    def __init__(self, matrices: list[NDArray[np.float64]], colour: int, depth: int) -> None:
        self.intrinsic_colour, self.intrinsic_depth = matrices[0], matrices[2]
        self.colour, self.depth = colour, depth
        self.depth_size = (0, 0)

    @classmethod
    def read(cls, data: BinaryReader) -> _Header:
        (version,) = data.take("I", "version")
        if version != _VERSION:
            raise InputError.single(data.shown, f"version {version}: only version 4 is read")
        (length,) = data.take("Q", "sensor name length")
        data.read(length, "sensor name")
        names = ("intrinsic_color", "extrinsic_color", "intrinsic_depth", "extrinsic_depth")
        matrices = [np.array(data.take("16f", n), dtype=np.float64).reshape(4, 4) for n in names]
        colour, depth = data.take("ii", "compression types")
        if colour not in _COLOUR:
            raise _refused(
                data, "colour compression", _COLOUR_NAMES.get(colour, colour), "png, jpeg"
            )
        if depth not in (0, 1):
            raise _refused(
                data, "depth compression", _DEPTH_NAMES.get(depth, depth), "raw_ushort, zlib_ushort"
            )
        header = cls(matrices, colour, depth)
        _, _, width, height = data.take("IIII", "image sizes")
        (shift,) = data.take("f", "depth shift")
        if shift != _DEPTH_SHIFT:
            raise _refused(data, "depth shift", f"{shift:g}", "1000 (millimetres)")
        if width * height * 2 > MAX_DECOMPRESSED_BYTES or width * height == 0:
            raise InputError.single(data.shown, f"depth size {width}x{height} is out of range")
        header.depth_size = (int(width), int(height))
        return header

    def write(self, dest: Path) -> None:
        (dest / "intrinsic").mkdir(parents=True, exist_ok=True)
        for name, matrix in (("color", self.intrinsic_colour), ("depth", self.intrinsic_depth)):
            np.savetxt(dest / "intrinsic" / f"intrinsic_{name}.txt", matrix, fmt="%.9g")
        for sub in ("color", "depth", "pose"):
            (dest / sub).mkdir(exist_ok=True)


def _refused(data: BinaryReader, field: str, value: object, accepted: str) -> InputError:
    return InputError.single(
        data.shown, f"{field} {value} is not supported (dcseg reads {accepted})"
    )


def _frame(data: BinaryReader, header: _Header, index: int, dest: Path) -> int:
    """Write frame ``index``; returns the bytes written."""
    field = f"frame {index}"
    c2w = np.array(data.take("16f", f"{field}: camera_to_world"), dtype=np.float64).reshape(4, 4)
    _, _, colour_bytes, depth_bytes = data.take("QQQQ", f"{field}: timestamps and sizes")
    colour = data.read(colour_bytes, f"{field}: colour")
    depth = _depth(data.read(depth_bytes, f"{field}: depth"), header, data.shown, field)
    (dest / "color" / f"{index}{_COLOUR[header.colour]}").write_bytes(colour)
    depth_path = dest / "depth" / f"{index}.png"
    write_image(depth_path, depth)
    np.savetxt(dest / "pose" / f"{index}.txt", c2w, fmt="%.9g")
    return len(colour) + depth_path.stat().st_size


def _depth(raw: bytes, header: _Header, shown: str, field: str) -> NDArray[np.uint16]:
    width, height = header.depth_size
    expected = width * height * 2
    if header.depth == 1:
        inflater = zlib.decompressobj()
        try:
            raw = inflater.decompress(raw, expected + 1)
        except zlib.error as exc:
            raise InputError.single(shown, f"{field}: depth is not zlib data ({exc})") from None
    if len(raw) != expected:
        raise InputError.single(
            shown,
            f"{field}: depth holds {len(raw)}{'+' if len(raw) > expected else ''} bytes, "
            f"expected {expected} ({width}x{height} uint16)",
        )
    return np.frombuffer(raw, dtype="<u2").reshape(height, width).astype(np.uint16)
