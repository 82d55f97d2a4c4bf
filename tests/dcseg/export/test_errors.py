"""Refused exports: every bad request names what is wrong and leaves no files behind."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from dcseg.errors import InputError
from dcseg.export import (
    FORMATS,
    ExportOptions,
    RunNotFinishedError,
    UnknownFormatError,
    UnknownInstanceError,
    export_run,
)


def test_unknown_format_names_the_formats(run: Path, tmp_path: Path) -> None:
    names = "ply, spz, splat, glb, glb-mesh, obj, usdz"
    with pytest.raises(UnknownFormatError, match=f"'gltf'.*{names}"):
        export_run(run, tmp_path / "out", "gltf")
    assert not (tmp_path / "out").exists()


def test_unknown_instances_are_all_named(run: Path, tmp_path: Path) -> None:
    with pytest.raises(UnknownInstanceError, match=r"\[7, 0\]; this run holds ids 1-3"):
        export_run(run, tmp_path, "ply", instances=[1, 7, 0])
    assert list(tmp_path.iterdir()) == []


def test_a_folder_without_run_json_is_not_finished(run: Path, tmp_path: Path) -> None:
    partial = tmp_path / "partial"
    shutil.copytree(run, partial)
    (partial / "run.json").unlink()
    with pytest.raises(RunNotFinishedError, match="no run.json"):
        export_run(partial, tmp_path / "out", "spz")


def test_a_trained_only_run_is_not_segmented(run: Path, tmp_path: Path) -> None:
    trained = tmp_path / "trained"
    shutil.copytree(run, trained)
    (trained / "scene_labelled.ply").unlink()
    with pytest.raises(RunNotFinishedError, match="not segmented .no scene_labelled.ply"):
        export_run(trained, tmp_path / "out", "ply")
    with pytest.raises(RunNotFinishedError, match="no such run folder"):
        export_run(tmp_path / "missing", tmp_path / "out", "ply")


def test_an_object_table_of_another_scene_is_refused(run: Path, tmp_path: Path) -> None:
    other = tmp_path / "other"
    shutil.copytree(run, other)
    body = json.loads((other / "instances.json").read_text())
    body["scene_sha256"] = "0" * 64
    (other / "instances.json").write_text(json.dumps(body))
    with pytest.raises(InputError, match="instances.json: scene_sha256 does not match"):
        export_run(other, tmp_path / "out", "ply")


@pytest.mark.parametrize(
    ("field", "value"),
    [("colour", "rainbow"), ("sh_degree", 4), ("max_faces", 0), ("voxel_size", -1.0)],
)
def test_options_out_of_range_name_the_field(field: str, value: object) -> None:
    with pytest.raises(InputError, match=f"^{field}: "):
        ExportOptions(**{field: value})  # type: ignore[arg-type]


def test_formats_are_the_documented_ones() -> None:
    assert FORMATS == ("ply", "spz", "splat", "glb", "glb-mesh", "obj", "usdz")
