"""``[M, H, W]`` stacks of binary masks: ``<stem>.npy``, or ``<stem>.npz`` with scores.

SAM's predictor, Grounded-SAM scripts and many notebooks end with a boolean (or 0/1, 0/255
uint8) array of masks; ``[M, 1, H, W]`` (SAM's ``multimask_output=False``) is read too. An
``.npz`` holds the stack as ``masks`` and, optionally, one value per mask in ``scores``,
``predicted_iou``, ``stability_score`` (:mod:`dcseg.io.mask_formats.scores`). Masks are
encoded one at a time (an ``.npy`` is memory-mapped), so the stack is never copied whole.
"""

from __future__ import annotations

import zipfile
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dcseg.errors import InputError
from dcseg.io.images import MAX_PIXELS, charge_pixels, display_path
from dcseg.io.mask_formats.rle import RLE, encode
from dcseg.io.mask_formats.scores import NPZ_SCORE_KEYS, MinScores
from dcseg.io.npy import NUMPY_FILE_ERRORS, npy_file_header, npy_header
from dcseg.types import AgnosticMasks

__all__ = ["is_stack", "read_stack", "stack_pixels"]

_MASK_DTYPES = "bu"
"""Bool or unsigned integers: non-zero = inside."""


def is_stack(path: Path) -> bool:
    """An ``.npz``, or an ``.npy`` of 3 or 4 dimensions (a 2D ``.npy`` is a label map)."""
    if path.suffix.lower() == ".npz":
        return True
    try:
        return len(npy_file_header(path)[0]) in (3, 4)
    except NUMPY_FILE_ERRORS:
        return False


def stack_pixels(path: Path) -> int | None:
    """``M * H * W`` of a stack from its header (nothing decompressed), or None if unreadable."""
    try:
        shape, _ = _header(path, path.name)
    except NUMPY_FILE_ERRORS:
        return None
    return int(np.prod(shape, dtype=np.int64))


def read_stack(path: Path, stem: str, root: Path, min_scores: MinScores) -> AgnosticMasks:
    """The non-empty masks of a stack that pass ``min_scores``, in stack order.

    The shape is checked (and charged to the pixel budget) from the array header before the
    masks are decompressed, so a small ``.npz`` cannot expand past the limits unseen.

    Raises:
        InputError: unreadable file, no ``masks`` array, a shape or dtype that is not a stack
            of binary masks, or a score array whose length is not the number of masks.
    """
    shown = display_path(path, root)
    try:
        count, height, width = _checked_shape(*_header(path, shown), shown)
        charge_pixels(count * height * width, shown)
        stack, scores = _load(path, shown)
    except NUMPY_FILE_ERRORS as err:
        if isinstance(err, InputError):
            raise
        raise InputError.single(shown, f"cannot read mask stack: {err}") from err
    stack = stack.reshape(count, height, width)
    for name, values in scores.items():
        if values.shape != (count,) or values.dtype.kind not in "fiu":
            reason = f"'{name}' must hold one number per mask ({count}), got shape {values.shape}"
            raise InputError.single(shown, reason)
    keep = min_scores.keeps_all({NPZ_SCORE_KEYS[k]: v for k, v in scores.items()}, count)
    rles: list[RLE] = [encode(stack[i] != 0) for i in np.flatnonzero(keep) if stack[i].any()]
    return AgnosticMasks(stem, height, width, tuple(rles), shown)


def _checked_shape(shape: tuple[int, ...], dtype: np.dtype[Any], shown: str) -> tuple[int, ...]:
    """``(M, H, W)`` of a binary-mask stack (``[M, 1, H, W]`` accepted), or InputError."""
    if len(shape) == 4 and shape[1] == 1:
        shape = (shape[0], shape[2], shape[3])
    if len(shape) != 3 or dtype.kind not in _MASK_DTYPES:
        reason = f"expected [M, H, W] bool or uint8 masks, got shape {shape} {dtype}"
        raise InputError.single(shown, reason)
    if shape[1] * shape[2] > MAX_PIXELS:
        reason = f"masks are {shape[2]}x{shape[1]}, above {MAX_PIXELS:,} pixels"
        raise InputError.single(shown, reason)
    return shape


def _header(path: Path, shown: str) -> tuple[tuple[int, ...], np.dtype[Any]]:
    """Shape and dtype of the stack, from the ``.npy`` header (inside the ``.npz`` zip)."""
    if path.suffix.lower() == ".npy":
        return npy_file_header(path)
    with zipfile.ZipFile(path) as archive:
        names = [n.removesuffix(".npy") for n in archive.namelist()]
        if "masks" not in names:
            found = ", ".join(names) or "none"
            raise InputError.single(shown, f"expected a 'masks' array (found: {found})")
        with archive.open("masks.npy") as member:
            return npy_header(member)


def _load(path: Path, shown: str) -> tuple[NDArray[Any], dict[str, NDArray[Any]]]:
    """The stack (memory-mapped for ``.npy``) and the score arrays an ``.npz`` holds."""
    if path.suffix.lower() == ".npy":
        return np.load(path, mmap_mode="r", allow_pickle=False), {}
    with np.load(path, allow_pickle=False) as archive:
        scores = {k: np.asarray(archive[k]) for k in NPZ_SCORE_KEYS if k in archive.files}
        return np.asarray(archive["masks"]), scores
