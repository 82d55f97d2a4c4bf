"""Class-aware maps and vocabularies: readers, writers and every error case."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from dcseg.errors import InputError
from dcseg.io.semantic import (
    read_semantic_maps,
    read_vocabulary,
    write_semantic_png,
    write_vocabulary,
)
from dcseg.types import SemanticMap, Vocabulary

VOCAB = Vocabulary(("wall", "floor", "chair", "table"))


def class_map(height: int = 4, width: int = 6) -> np.ndarray:
    """An int32 map using every class and -1."""
    classes = np.arange(height * width, dtype=np.int32).reshape(height, width) % 5 - 1
    return classes


def only_problem(call: object) -> str:
    """The single problem message an InputError carries."""
    assert callable(call)
    with pytest.raises(InputError) as info:
        call()
    assert len(info.value.problems) == 1, info.value.problems
    return str(info.value.problems[0])


# --------------------------------------------------------------------------- vocabulary


def test_vocabulary_txt_skips_blank_lines_keeps_order(tmp_path: Path) -> None:
    path = tmp_path / "classes.txt"
    path.write_text("  wall \n\nfloor\n\t\nchair\n")
    vocab = read_vocabulary(path)
    assert vocab.names == ("wall", "floor", "chair")
    assert vocab.source == str(path)
    assert len(vocab) == 3


@pytest.mark.parametrize("name", ["v.txt", "v.json", "sub/v.JSON"])
def test_vocabulary_round_trip(tmp_path: Path, name: str) -> None:
    path = tmp_path / name
    vocab = Vocabulary(("wall", "floor", "dining table", "caf\u00e9"))
    write_vocabulary(path, vocab)
    assert read_vocabulary(path).names == vocab.names


def test_vocabulary_json_list(tmp_path: Path) -> None:
    path = tmp_path / "v.json"
    path.write_text(json.dumps(["a", "b"]))
    assert read_vocabulary(path).names == ("a", "b")


def test_vocabulary_txt_duplicate_names_line_numbers(tmp_path: Path) -> None:
    path = tmp_path / "v.txt"
    path.write_text("wall\nchair\n\nchair\n")
    reason = only_problem(lambda: read_vocabulary(path))
    assert reason == "v.txt: class 'chair' appears more than once (lines 2, 4)"


@pytest.mark.parametrize(
    "text,message",
    [
        ("\n  \n", "v.txt: vocabulary is empty: no class names found"),
    ],
)
def test_vocabulary_txt_errors(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "v.txt"
    path.write_text(text)
    assert only_problem(lambda: read_vocabulary(path)) == message


@pytest.mark.parametrize(
    "text,message",
    [
        ("[]", "v.json: vocabulary is empty: no class names found"),
        ('{"classes": ["a"]}', "v.json: expected a JSON list of class names, got dict"),
        ('["a", 3]', "v.json: entry 2: class name must be a string, got int 3"),
        ('["a", " "]', "v.json: entry 2: class name is blank"),
        ('["a", "b", "a"]', "v.json: class 'a' appears more than once (entries 1, 3)"),
        ('["a",\n  ]', "v.json: malformed JSON at line 2, column 3: Expecting value"),
    ],
)
def test_vocabulary_json_errors(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "v.json"
    path.write_text(text)
    with pytest.raises(InputError) as info:
        read_vocabulary(path)
    assert str(info.value) == message


def test_vocabulary_other_errors(tmp_path: Path) -> None:
    path = tmp_path / "v.yaml"
    path.write_text("- a")
    assert "unsupported vocabulary format '.yaml'" in only_problem(lambda: read_vocabulary(path))
    missing = tmp_path / "missing.txt"
    assert "missing.txt: cannot read vocabulary" in only_problem(lambda: read_vocabulary(missing))
    with pytest.raises(ValueError, match="use .json"):
        write_vocabulary(tmp_path / "x.txt", Vocabulary(("a\nb",)))
    with pytest.raises(ValueError, match="unsupported vocabulary format"):
        write_vocabulary(tmp_path / "x.csv", VOCAB)


# --------------------------------------------------------------------------- semantic maps


@pytest.mark.parametrize("n_classes,dtype", [(4, np.uint8), (300, np.uint16)])
def test_semantic_png_round_trip(tmp_path: Path, n_classes: int, dtype: type) -> None:
    classes = class_map()
    write_semantic_png(tmp_path / "maps" / "f0.png", SemanticMap("f0", classes), n_classes)
    stored = cv2.imread(str(tmp_path / "maps" / "f0.png"), cv2.IMREAD_UNCHANGED)
    assert stored is not None
    assert stored.dtype == dtype
    assert int(stored.max()) == np.iinfo(dtype).max  # the unlabelled sentinel
    vocab = Vocabulary(tuple(f"c{i}" for i in range(n_classes)))
    maps = read_semantic_maps(tmp_path / "maps", vocab)
    assert list(maps) == ["f0"]
    assert maps["f0"].classes.dtype == np.int32
    np.testing.assert_array_equal(maps["f0"].classes, classes)
    assert maps["f0"].source == "maps/f0.png"


@pytest.mark.parametrize("dtype", [np.int64, np.int16, np.uint8])
def test_semantic_npy(tmp_path: Path, dtype: type) -> None:
    raw: np.ndarray = np.array([[0, 1, 2], [3, 0, 1]], dtype=dtype)
    if np.issubdtype(dtype, np.signedinteger):
        raw[0, 0] = -7
    np.save(tmp_path / "f.npy", raw)
    classes = read_semantic_maps(tmp_path, VOCAB)["f"].classes
    expected = raw.astype(np.int32)
    expected[expected < 0] = -1
    np.testing.assert_array_equal(classes, expected)
    assert classes.dtype == np.int32


def test_semantic_rescale_nearest(tmp_path: Path) -> None:
    raw = np.arange(16, dtype=np.int32).reshape(4, 4) % 4
    np.save(tmp_path / "f.npy", raw)
    up = read_semantic_maps(tmp_path, VOCAB, size=(8, 8))["f"].classes
    np.testing.assert_array_equal(up, np.repeat(np.repeat(raw, 2, axis=0), 2, axis=1))
    down = read_semantic_maps(tmp_path, VOCAB, size=(2, 2))["f"].classes
    np.testing.assert_array_equal(down, raw[1::2, 1::2])


def test_semantic_ignores_hidden_and_unknown(tmp_path: Path) -> None:
    np.save(tmp_path / "b.npy", np.zeros((2, 2), np.int32))
    (tmp_path / "notes.txt").write_text("x")
    (tmp_path / ".a.png").write_bytes(b"junk")
    (tmp_path / "sub").mkdir()
    assert list(read_semantic_maps(tmp_path, VOCAB)) == ["b"]


def test_semantic_out_of_range_names_value_and_pixels(tmp_path: Path) -> None:
    raw = np.zeros((3, 3), dtype=np.uint8)
    raw[0, :2] = 7
    raw[2, 2] = 4
    cv2.imwrite(str(tmp_path / "f.png"), raw)
    reason = only_problem(lambda: read_semantic_maps(tmp_path, VOCAB))
    assert reason == (
        f"{tmp_path.name}/f.png: class index out of range for a vocabulary of 4 classes: "
        "4 (1 pixel), 7 (2 pixels)"
    )


def test_semantic_out_of_range_lists_a_few_values(tmp_path: Path) -> None:
    np.save(tmp_path / "f.npy", np.arange(20, dtype=np.int32).reshape(4, 5))
    reason = only_problem(lambda: read_semantic_maps(tmp_path, VOCAB))
    assert reason.endswith(
        "4 (1 pixel), 5 (1 pixel), 6 (1 pixel), 7 (1 pixel), 8 (1 pixel) and 11 more value(s)"
    )


def test_semantic_bad_files_all_reported(tmp_path: Path) -> None:
    cv2.imwrite(str(tmp_path / "rgb.png"), np.zeros((4, 4, 3), np.uint8))
    np.save(tmp_path / "float.npy", np.zeros((4, 4), np.float32))
    np.save(tmp_path / "cube.npy", np.zeros((2, 4, 4), np.int32))
    (tmp_path / "broken.png").write_bytes(b"not a png")
    np.save(tmp_path / "dup.npy", np.zeros((2, 2), np.int32))
    cv2.imwrite(str(tmp_path / "dup.png"), np.zeros((2, 2), np.uint8))
    with pytest.raises(InputError) as info:
        read_semantic_maps(tmp_path, VOCAB)
    name = tmp_path.name
    assert sorted(str(p) for p in info.value.problems) == [
        f"{name}/broken.png: cannot decode image (corrupt or not an image)",
        f"{name}/cube.npy: expected a 2D class map [H, W], got shape (2, 4, 4)",
        f"{name}/dup.npy: frame 'dup' has class maps in several formats: "
        f"{name}/dup.npy, {name}/dup.png",
        f"{name}/float.npy: expected an integer class map, got float32",
        f"{name}/rgb.png: expected a single-channel class map, got 3 channels",
    ]


def test_semantic_missing_folder(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="semantic map folder not found"):
        read_semantic_maps(tmp_path / "nope", VOCAB)


def test_write_semantic_png_rejects_bad_input(tmp_path: Path) -> None:
    m = SemanticMap("f", class_map())
    with pytest.raises(ValueError, match=r"class indices must be in \[-1, 2\), got \[-1, 3\]"):
        write_semantic_png(tmp_path / "f.png", m, 2)
    with pytest.raises(ValueError, match="n_classes must be in"):
        write_semantic_png(tmp_path / "f.png", m, 0)
    with pytest.raises(ValueError, match="written as .png"):
        write_semantic_png(tmp_path / "f.jpg", m, 4)
