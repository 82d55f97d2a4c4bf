"""Mask files written in code to each format's published specification, for the reader tests.

* Palette PNG: PNG 1.2 (ISO/IEC 15948), colour type 3, ``PLTE`` + ``IDAT`` rows with filter 0.
* Panoptic PNG: COCO panoptic (panopticapi ``id2rgb``): ``id = R + 256 G + 256^2 B``.
* COCO instances: ``images`` / ``annotations`` / ``categories``, polygons ``[x1, y1, x2, ...]``.
"""

from __future__ import annotations

import json
import struct
import zlib
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

VOC_PALETTE = [
    (((i >> 0) & 1) << 7 | ((i >> 3) & 1) << 6, ((i >> 1) & 1) << 7, ((i >> 2) & 1) << 7)
    for i in range(256)
]
"""A VOC-like colour table (distinct colours for the low indices; enough for tests)."""


def _chunk(kind: bytes, body: bytes) -> bytes:
    crc = zlib.crc32(kind + body) & 0xFFFFFFFF
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", crc)


def write_palette_png(
    path: Path,
    indices: NDArray[Any],
    palette: list[tuple[int, int, int]] | None = None,
    *,
    bit_depth: int = 8,
    transparent: bool = False,
) -> Path:
    """An indexed-colour PNG of ``indices`` (``[H, W]`` ints below ``2**bit_depth``)."""
    height, width = indices.shape
    table = (palette or VOC_PALETTE)[: 1 << bit_depth]
    per_byte = 8 // bit_depth
    rows = []
    for row in indices.astype(np.uint8):
        padded = np.zeros(-(-width // per_byte) * per_byte, dtype=np.uint8)
        padded[:width] = row
        packed = np.zeros(padded.size // per_byte, dtype=np.uint8)
        for k in range(per_byte):
            packed |= padded[k::per_byte] << (8 - bit_depth * (k + 1))
        rows.append(b"\x00" + packed.tobytes())
    header = struct.pack(">IIBBBBB", width, height, bit_depth, 3, 0, 0, 0)
    chunks = [_chunk(b"IHDR", header), _chunk(b"PLTE", bytes(v for c in table for v in c))]
    if transparent:
        chunks.append(_chunk(b"tRNS", b"\x00"))
    chunks += [_chunk(b"IDAT", zlib.compress(b"".join(rows))), _chunk(b"IEND", b"")]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + b"".join(chunks))
    return path


def write_panoptic_png(path: Path, ids: NDArray[Any]) -> Path:
    """An RGB PNG of panoptic ids (panopticapi ``id2rgb``: R = id % 256, G, B the next bytes)."""
    ids = ids.astype(np.int64)
    rgb = np.stack([ids % 256, ids // 256 % 256, ids // 256**2 % 256], axis=-1).astype(np.uint8)
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), rgb[:, :, ::-1])
    return path


def write_json(path: Path, data: Any) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data), encoding="utf-8")
    return path
