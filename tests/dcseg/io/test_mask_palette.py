"""Palette PNGs (DAVIS, SAM2, DEVA, VOC) read by index, as agnostic masks and as class maps."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from dcseg.errors import InputError
from dcseg.io.images import pixel_budget
from dcseg.io.mask_formats.palette import is_palette_png, read_palette_indices
from dcseg.io.masks import decode_masks, read_agnostic_masks
from dcseg.io.semantic import read_semantic_maps
from dcseg.types import Vocabulary
from tests.dcseg.io.mask_files import write_palette_png


def davis_map() -> np.ndarray:
    """Objects 1..3 on background 0, and a VOC-style 255 boundary."""
    labels = np.zeros((6, 8), dtype=np.uint8)
    labels[1:3, 1:4] = 1
    labels[3:6, 0:2] = 2
    labels[4:6, 5:8] = 3
    labels[0, :] = 255
    return labels


@pytest.mark.parametrize("bit_depth", [1, 2, 4, 8])
def test_indices_at_every_bit_depth(tmp_path: Path, bit_depth: int) -> None:
    rng = np.random.default_rng(bit_depth)
    indices = rng.integers(0, 2**bit_depth, size=(5, 11))
    path = write_palette_png(tmp_path / "a.png", indices, bit_depth=bit_depth, transparent=True)
    assert is_palette_png(path)
    np.testing.assert_array_equal(read_palette_indices(path), indices)


def test_indices_do_not_depend_on_the_colour_table(tmp_path: Path) -> None:
    """Two files with the same indices and different (even repeated) colours read alike."""
    indices = davis_map()
    black = [(0, 0, 0)] * 256
    a = read_palette_indices(write_palette_png(tmp_path / "a.png", indices))
    b = read_palette_indices(write_palette_png(tmp_path / "b.png", indices, black))
    np.testing.assert_array_equal(a, indices)
    np.testing.assert_array_equal(b, indices)


def test_agnostic_palette_one_mask_per_object_void_ignored(tmp_path: Path) -> None:
    labels = davis_map()
    write_palette_png(tmp_path / "masks" / "00000.png", labels)
    masks = read_agnostic_masks(tmp_path / "masks")["00000"]
    dense = decode_masks(masks)
    assert len(masks) == 3
    for i, value in enumerate((1, 2, 3)):
        np.testing.assert_array_equal(dense[i], labels == value)


def test_semantic_palette_index_is_class_255_unlabelled(tmp_path: Path) -> None:
    labels = davis_map()
    write_palette_png(tmp_path / "sem" / "f1.png", labels)
    vocabulary = Vocabulary(("background", "chair", "table", "sofa"))
    classes = read_semantic_maps(tmp_path / "sem", vocabulary)["f1"].classes
    np.testing.assert_array_equal(classes, np.where(labels == 255, -1, labels.astype(np.int32)))


def test_semantic_palette_index_beyond_vocabulary(tmp_path: Path) -> None:
    write_palette_png(tmp_path / "sem" / "f1.png", davis_map())
    with pytest.raises(InputError) as info:
        read_semantic_maps(tmp_path / "sem", Vocabulary(("background", "chair")))
    assert info.value.problems[0].path == "sem/f1.png"
    assert "3 (6 pixels)" in info.value.problems[0].reason


def test_grey_png_is_not_palette(tmp_path: Path) -> None:
    import cv2

    cv2.imwrite(str(tmp_path / "g.png"), davis_map())
    assert not is_palette_png(tmp_path / "g.png")
    with pytest.raises(InputError, match="not a palette PNG"):
        read_palette_indices(tmp_path / "g.png")


def test_corrupt_palette_png_names_the_file(tmp_path: Path) -> None:
    path = write_palette_png(tmp_path / "masks" / "f.png", davis_map())
    path.write_bytes(path.read_bytes()[:-30])
    with pytest.raises(InputError) as info:
        read_agnostic_masks(tmp_path / "masks")
    assert info.value.problems[0].path == "masks/f.png"
    assert "corrupt" in info.value.problems[0].reason


def test_palette_png_counts_against_the_pixel_budget(tmp_path: Path) -> None:
    path = write_palette_png(tmp_path / "f.png", davis_map())
    with pixel_budget(47), pytest.raises(InputError, match="pixels in total"):
        read_palette_indices(path)
