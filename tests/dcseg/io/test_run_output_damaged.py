"""A damaged run folder (a partial copy, an edit) is named, not a JSON or plyfile traceback."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from dcseg.errors import InputError
from dcseg.io.ply import write_gaussians_ply
from dcseg.io.run_output import load_labels
from tests.dcseg.io.test_ply_file import flat_gaussians


def labelled_run(run: Path) -> Path:
    ids = np.arange(4, dtype=np.int32)
    run.mkdir()
    extra = {"instance_id": ids, "semantic_id": ids, "cluster_id": ids}
    write_gaussians_ply(run / "scene_labelled.ply", flat_gaussians(4), extra=extra)
    (run / "run.json").write_text("{}")
    return run


def test_labels_read_back(tmp_path: Path) -> None:
    labels = load_labels(labelled_run(tmp_path / "run"), [])
    assert labels.semantic_ids.tolist() == [0, 1, 2, 3]


def test_run_json_that_is_not_json_is_named(tmp_path: Path) -> None:
    run = labelled_run(tmp_path / "run")
    (run / "run.json").write_text('{"capture": ')
    with pytest.raises(InputError) as info:
        load_labels(run, [])
    assert str(info.value) == (
        f"{run / 'run.json'}: invalid JSON (Expecting value at line 1 column 13)"
    )
    (run / "run.json").write_text("[1, 2]")
    with pytest.raises(InputError, match=r"run\.json: expected a JSON object"):
        load_labels(run, [])


def test_a_cut_labelled_ply_is_named(tmp_path: Path) -> None:
    run = labelled_run(tmp_path / "run")
    path = run / "scene_labelled.ply"
    path.write_bytes(path.read_bytes()[:-40])
    with pytest.raises(InputError) as info:
        load_labels(run, [])
    assert str(info.value).startswith(f"{path}: not a readable PLY file")
