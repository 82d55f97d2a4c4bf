"""A required JSON field set to null is named (it read as a present value and crashed later)."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from dcseg.errors import InputError
from dcseg.io.captures import read_capture
from tests.dcseg.io.layouts import make_scene, write_replica
from tests.dcseg.io.test_captures_polycam import write_polycam
from tests.dcseg.io.test_captures_record3d import write_r3d_folder
from tests.dcseg.io.test_captures_redwood import write_redwood

Writer = Callable[[Path], Path]
CASES: list[tuple[Writer, str, tuple[str, ...], str]] = [
    (lambda r: write_replica(make_scene(), r), "cam_params.json", ("camera", "cx"), "camera.cx"),
    (lambda r: write_redwood(make_scene(), r), "camera_intrinsic.json", ("width",), "width"),
    (write_polycam, "keyframes/cameras/10500.json", ("fy",), "fy"),
    (write_r3d_folder, "metadata", ("K",), "K"),
    (write_r3d_folder, "metadata", ("poses",), "poses"),
]


def set_null(path: Path, keys: tuple[str, ...]) -> None:
    doc = json.loads(path.read_text())
    node: Any = doc
    for key in keys[:-1]:
        node = node[key]
    node[keys[-1]] = None
    path.write_text(json.dumps(doc))


@pytest.mark.parametrize(("write", "file", "keys", "field"), CASES)
def test_required_null_field_is_named(
    tmp_path: Path, write: Writer, file: str, keys: tuple[str, ...], field: str
) -> None:
    root = tmp_path / "capture"
    write(root)
    set_null(root / file, keys)
    with pytest.raises(InputError) as info:
        read_capture(root)
    assert f"{file}: {field}: must not be null" in str(info.value)
