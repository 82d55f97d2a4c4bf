"""The ``.splat`` format of antimatter15's WebGL viewer (also read by SuperSplat and Spark).

32 bytes per Gaussian, little-endian, no header::

    position  3 x float32   world coordinates
    scale     3 x float32   linear (exp of the log scale)
    colour    4 x uint8     RGB of the SH DC term, alpha = sigmoid(opacity), each * 255
    rotation  4 x uint8     unit quaternion w, x, y, z, each as round(q * 128 + 128) in 0..255

View-dependent colour (higher SH) is dropped by the format. Gaussians are written in the
order given (grouped by object in scene files; viewers depth-sort at render time).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from dcseg.export.appearance import gaussian_rgb
from dcseg.export.options import ExportOptions
from dcseg.io.splat_table import SplatTable

SPLAT_DTYPE = np.dtype(
    [("position", "<f4", 3), ("scale", "<f4", 3), ("rgba", "u1", 4), ("rotation", "u1", 4)]
)
assert SPLAT_DTYPE.itemsize == 32


def encode_splat(table: SplatTable) -> NDArray[np.void]:
    """``table`` as ``[N]`` records of :data:`SPLAT_DTYPE`."""
    out = np.empty(len(table), SPLAT_DTYPE)
    out["position"] = table.means
    out["scale"] = np.exp(table.log_scales)
    alpha = 1.0 / (1.0 + np.exp(-table.opacity_logits.astype(np.float64)))
    out["rgba"][:, :3] = gaussian_rgb(table)
    out["rgba"][:, 3] = np.round(alpha * 255.0).astype(np.uint8)
    norm = np.linalg.norm(table.quats, axis=1, keepdims=True)
    unit = table.quats / np.where(norm > 0, norm, 1.0)
    out["rotation"] = np.clip(np.round(unit * 128.0 + 128.0), 0, 255).astype(np.uint8)
    return out


def write_splat(path: Path, table: SplatTable, options: ExportOptions) -> None:
    """Write ``table`` as a ``.splat`` file (``options`` has nothing for this format)."""
    path.write_bytes(encode_splat(table).tobytes())


def read_splat(path: Path) -> NDArray[np.void]:
    """The records of a ``.splat`` file (its size must be a multiple of 32 bytes)."""
    raw = path.read_bytes()
    if len(raw) % SPLAT_DTYPE.itemsize:
        raise ValueError(f"{path}: size {len(raw)} is not a multiple of 32 bytes")
    return np.frombuffer(raw, SPLAT_DTYPE)
