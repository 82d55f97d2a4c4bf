"""``.npy`` label and class maps: a damaged header or an absurd shape is named, never loaded."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest
from numpy.lib import format as npy_format

from dcseg.errors import InputError
from dcseg.io.images import MAX_PIXELS
from dcseg.io.masks import read_agnostic_masks
from dcseg.io.semantic import read_semantic_maps
from dcseg.types import Vocabulary


def damaged(path: Path, old: bytes, new: bytes) -> Path:
    """An ``.npy`` of a small label map whose header text has ``old`` replaced by ``new``
    (padded to the same length, so only the header's meaning changes)."""
    np.save(path, np.zeros((6, 8), dtype=np.uint8))
    data = path.read_bytes()
    assert old in data
    path.write_bytes(data.replace(old, new.ljust(len(old)), 1))
    return path


@pytest.mark.parametrize(
    ("old", "new"),
    [
        (b"(6, 8)", b"(6, 8"),  # tokenize.TokenError inside numpy's header parser
        (b"(6, 8)", b"6 8"),  # SyntaxError from ast.literal_eval
        (b"'descr'", b"'descr"),
    ],
)
def test_damaged_header_is_named_by_both_readers(tmp_path: Path, old: bytes, new: bytes) -> None:
    (tmp_path / "m").mkdir()
    damaged(tmp_path / "m" / "f.npy", old, new)
    with pytest.raises(InputError, match=r"^m/f\.npy: cannot read \.npy array: "):
        read_agnostic_masks(tmp_path / "m")
    with pytest.raises(InputError, match=r"^m/f\.npy: cannot read \.npy array: "):
        read_semantic_maps(tmp_path / "m", Vocabulary(("wall",)))


def test_absurd_shape_is_refused_from_the_header(tmp_path: Path) -> None:
    """A 12-byte payload claiming 200000 x 200000 uint16 (75 GiB): refused before numpy
    allocates it."""
    header = io.BytesIO()
    npy_format.write_array_header_1_0(
        header, {"descr": "<u2", "fortran_order": False, "shape": (200000, 200000)}
    )
    (tmp_path / "m").mkdir()
    (tmp_path / "m" / "f.npy").write_bytes(header.getvalue() + bytes(12))
    message = (
        f"m/f.npy: array of shape (200000, 200000) is above the limit of {MAX_PIXELS:,} pixels"
    )
    with pytest.raises(InputError) as info:
        read_agnostic_masks(tmp_path / "m")
    assert str(info.value) == message
    with pytest.raises(InputError) as info:
        read_semantic_maps(tmp_path / "m", Vocabulary(("wall",)))
    assert str(info.value) == message
