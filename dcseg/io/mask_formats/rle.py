"""COCO run-length encodings: validation, decoding and encoding of one mask.

Shared by every mask format reader: masks stay compact as ``{"size": [H, W], "counts": bytes}``
(pycocotools' compressed form) and are decoded one at a time.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pycocotools.mask as mask_util
from numpy.typing import NDArray

from dcseg.io.images import MAX_PIXELS

__all__ = ["RLE", "decode_counts", "decode_rle", "encode", "is_count", "to_rle"]

RLE = dict[str, Any]


def to_rle(seg: Any) -> tuple[RLE | None, str]:
    """A validated compressed RLE from a COCO segmentation, or None and the reason."""
    if not isinstance(seg, dict) or "size" not in seg or "counts" not in seg:
        return None, "segmentation must be a COCO RLE with 'size' and 'counts'"
    hw = seg["size"]
    if not (isinstance(hw, list) and len(hw) == 2 and all(is_count(v) for v in hw)):
        return None, f"RLE size must be [height, width], got {hw!r}"
    height, width = hw
    if height * width > MAX_PIXELS:
        return None, f"RLE size {width}x{height} is above the limit of {MAX_PIXELS:,} pixels"
    counts = seg["counts"]
    if isinstance(counts, list):
        runs = np.asarray(counts) if all(is_count(c) for c in counts) else None
    elif isinstance(counts, str | bytes):
        raw = counts.encode("utf-8") if isinstance(counts, str) else counts
        runs = decode_counts(raw)  # non-ASCII bytes are >= 128 and are rejected
    else:
        return None, f"RLE counts must be a string or a list, got {type(counts).__name__}"
    if runs is None or int(np.sum(runs)) != height * width:
        return None, f"RLE counts are corrupt (they do not cover the {width}x{height} mask)"
    if isinstance(counts, list):
        return mask_util.frPyObjects(seg, height, width), ""
    return {"size": [height, width], "counts": raw}, ""


def is_count(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0


def decode_counts(counts: bytes) -> NDArray[np.int64] | None:
    """Run lengths of a COCO compressed RLE string (pycocotools ``rleFrString``), or None.

    Vectorised: every character holds 5 bits of a value, with 0x20 = "more characters follow"
    and 0x10 on the last character = negative; values from the fourth on are deltas to the
    value two places back. Returns None when the string is malformed or a run is negative.
    """
    chars = np.frombuffer(counts, dtype=np.uint8).astype(np.int64) - 48
    if chars.size == 0:
        return np.zeros(0, dtype=np.int64)
    if chars.min() < 0 or chars.max() >= 64 or chars[-1] & 0x20:
        return None
    ends = np.flatnonzero((chars & 0x20) == 0)
    starts = np.concatenate(([0], ends[:-1] + 1))
    lengths = ends - starts + 1
    if lengths.max() > 12:
        return None
    shift = 5 * (np.arange(chars.size) - np.repeat(starts, lengths))
    values = np.add.reduceat((chars & 0x1F) << shift, starts)
    values -= np.where(chars[ends] & 0x10, 1 << (5 * lengths), 0)
    runs = values.copy()
    runs[1::2] = np.cumsum(values[1::2])
    runs[2::2] = np.cumsum(values[2::2])
    return runs if runs.min() >= 0 else None


def decode_rle(rle: RLE) -> NDArray[np.bool_]:
    """Decode one validated compressed RLE into an ``[H, W]`` boolean mask.

    Done in numpy rather than ``pycocotools.mask.decode``, which warns under numpy 2 and does
    not bounds-check its input.
    """
    height, width = (int(v) for v in rle["size"])
    runs = decode_counts(rle["counts"])
    if runs is None or int(runs.sum()) != height * width:
        raise ValueError(f"corrupt RLE counts for a {width}x{height} mask")
    on = (np.arange(runs.size) % 2).astype(np.bool_)
    return np.repeat(on, runs).reshape(width, height).T


def encode(mask: NDArray[Any]) -> RLE:
    """Compressed COCO RLE (bytes counts) of one ``[H, W]`` mask."""
    rle: RLE = mask_util.encode(np.asfortranarray(mask, dtype=np.uint8))
    return {"size": [int(v) for v in rle["size"]], "counts": rle["counts"]}
