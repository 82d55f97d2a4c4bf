"""Ground-truth PLY: ascii/binary reading, ignored labels, the writer and every error case."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import plyfile
import pytest

from dcseg.errors import InputError
from dcseg.io.ground_truth import (
    read_ground_truth,
    read_ground_truth_points,
    write_ground_truth_ply,
)
from dcseg.types import GroundTruth


def vertices(n: int = 5, *, instance: bool = True) -> np.ndarray:
    fields = [("x", "f4"), ("y", "f4"), ("z", "f4"), ("label", "i2")]
    fields += [("instance", "i4")] if instance else []
    data = np.zeros(n, dtype=fields)
    data["x"] = np.arange(n)
    data["y"] = np.arange(n) * 0.5
    data["z"] = -1.25
    data["label"] = [0, 1, 2, -1, 9][:n]
    if instance:
        data["instance"] = [3, 3, -5, 4, 4][:n]
    return data


def write_ply(path: Path, data: np.ndarray, *, text: bool, name: str = "vertex") -> Path:
    plyfile.PlyData([plyfile.PlyElement.describe(data, name)], text=text).write(str(path))
    return path


def read_error(path: Path, n_classes: int = 3) -> str:
    with pytest.raises(InputError) as info:
        read_ground_truth(path, n_classes)
    assert len(info.value.problems) == 1
    return str(info.value)


@pytest.mark.parametrize("text", [True, False], ids=["ascii", "binary"])
def test_read_ascii_and_binary(
    tmp_path: Path, text: bool, caplog: pytest.LogCaptureFixture
) -> None:
    path = write_ply(tmp_path / "gt.ply", vertices(), text=text)
    with caplog.at_level(logging.INFO, logger="dcseg.io.ground_truth"):
        gt = read_ground_truth(path, n_classes=3)
    assert "gt.ply: 2 of 5 points have labels outside [0, 3) and are ignored" in caplog.text
    assert gt.points.dtype == np.float64 and gt.points.shape == (5, 3)
    np.testing.assert_array_equal(gt.points[:, 0], np.arange(5))
    np.testing.assert_array_equal(gt.points[:, 2], -1.25)
    assert gt.labels.dtype == np.int64
    assert gt.labels.tolist() == [0, 1, 2, -1, -1]
    assert gt.instances is not None and gt.instances.tolist() == [3, 3, -1, 4, 4]
    assert gt.source == str(path)


def test_read_without_instance(tmp_path: Path) -> None:
    path = write_ply(tmp_path / "gt.ply", vertices(instance=False), text=False)
    gt = read_ground_truth(path, n_classes=10)
    assert gt.instances is None
    assert gt.labels.tolist() == [0, 1, 2, -1, 9]


def test_points_alone_are_read_without_a_word_about_labels(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    path = write_ply(tmp_path / "gt.ply", vertices(), text=False)
    with caplog.at_level(logging.INFO, logger="dcseg.io.ground_truth"):
        points = read_ground_truth_points(path)
    assert caplog.text == ""
    np.testing.assert_array_equal(points, read_ground_truth(path, 3).points)
    with pytest.raises(InputError, match="not found"):
        read_ground_truth_points(tmp_path / "missing.ply")


def test_write_round_trip(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    gt = GroundTruth(
        points=rng.normal(size=(7, 3)),
        labels=np.array([0, 1, -1, 2, 2, 0, 1], dtype=np.int64),
        instances=np.array([1, 1, -1, 2, 2, 3, 3], dtype=np.int64),
    )
    path = tmp_path / "out" / "gt.ply"
    write_ground_truth_ply(path, gt)
    ply = plyfile.PlyData.read(str(path))
    assert not ply.text and ply.byte_order == "<"
    assert ply["vertex"].data.dtype["label"] == np.dtype("<i4")
    again = read_ground_truth(path, n_classes=3)
    np.testing.assert_array_equal(again.points, gt.points)
    np.testing.assert_array_equal(again.labels, gt.labels)
    assert again.instances is not None
    np.testing.assert_array_equal(again.instances, gt.instances)


def test_write_without_instances(tmp_path: Path) -> None:
    gt = GroundTruth(np.zeros((2, 3)), np.array([0, -1], dtype=np.int64))
    write_ground_truth_ply(tmp_path / "gt.ply", gt)
    names = [p.name for p in plyfile.PlyData.read(str(tmp_path / "gt.ply"))["vertex"].properties]
    assert names == ["x", "y", "z", "label"]
    assert read_ground_truth(tmp_path / "gt.ply", 1).instances is None


def test_error_missing_label_lists_found_properties(tmp_path: Path) -> None:
    data = np.zeros(2, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("red", "u1")])
    path = write_ply(tmp_path / "gt.ply", data, text=True)
    assert (
        read_error(path) == "gt.ply: vertex element has no 'label' property (found: x, y, z, red)"
    )


def test_error_missing_coordinates(tmp_path: Path) -> None:
    data = np.zeros(2, dtype=[("x", "f4"), ("label", "i4")])
    path = write_ply(tmp_path / "gt.ply", data, text=True)
    assert read_error(path) == "gt.ply: vertex element has no 'y', 'z' properties (found: x, label)"


def test_error_no_vertex_element(tmp_path: Path) -> None:
    path = write_ply(tmp_path / "gt.ply", vertices(), text=True, name="point")
    assert read_error(path) == "gt.ply: PLY has no vertex element (elements: point)"


def test_error_not_a_ply(tmp_path: Path) -> None:
    path = tmp_path / "gt.ply"
    path.write_text("hello\n")
    assert read_error(path).startswith("gt.ply: not a readable PLY file")


def test_error_truncated_binary(tmp_path: Path) -> None:
    path = write_ply(tmp_path / "gt.ply", vertices(), text=False)
    path.write_bytes(path.read_bytes()[:-7])
    assert read_error(path).startswith("gt.ply: not a readable PLY file")


def test_error_missing_file(tmp_path: Path) -> None:
    assert read_error(tmp_path / "gt.ply") == "gt.ply: ground-truth file not found"


def test_error_non_finite_coordinates(tmp_path: Path) -> None:
    data = vertices()
    data["y"][[1, 3]] = [np.nan, np.inf]
    path = write_ply(tmp_path / "gt.ply", data, text=False)
    assert read_error(path) == ("gt.ply: 2 vertices have non-finite coordinates (first: vertex 1)")


def test_error_float_labels(tmp_path: Path) -> None:
    data = np.zeros(2, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("label", "f4")])
    path = write_ply(tmp_path / "gt.ply", data, text=True)
    assert read_error(path) == "gt.ply: 'label' must be an integer property, got float32"


def test_error_empty_vertex_element(tmp_path: Path) -> None:
    path = write_ply(tmp_path / "gt.ply", vertices()[:0], text=True)
    assert read_error(path) == "gt.ply: vertex element is empty: no ground-truth points"


def test_n_classes_must_not_be_negative(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="n_classes must be >= 0"):
        read_ground_truth(tmp_path / "gt.ply", -1)


def test_without_a_vocabulary_every_label_is_ignored_and_instances_kept(tmp_path: Path) -> None:
    gt = read_ground_truth(write_ply(tmp_path / "gt.ply", vertices(), text=False), 0)
    assert (gt.labels == -1).all() and gt.instances is not None and (gt.instances >= 0).any()


def test_write_rejects_mismatched_shapes(tmp_path: Path) -> None:
    gt = GroundTruth(np.zeros((3, 3)), np.zeros(2, dtype=np.int64))
    with pytest.raises(ValueError, match="points must be"):
        write_ground_truth_ply(tmp_path / "gt.ply", gt)
