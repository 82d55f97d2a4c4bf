"""Reading stored ``.npz`` members straight from the file, as numpy.load would."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from dcseg.errors import InputError
from dcseg.io.npz import read_stored
from dcseg.io.run_state import _load_npz


def arrays() -> dict[str, Any]:
    rng = np.random.default_rng(0)
    return {
        "ids": rng.integers(0, 1000, 5000).astype(np.int32),
        "weights": rng.random(5000).astype(np.float16),
        "counts": rng.integers(0, 255, (48, 64)).astype(np.uint8),
        "fortran": np.asfortranarray(rng.random((7, 5))),
        "scalar": np.array(3.5),
        "empty": np.zeros((0, 3), dtype=np.int64),
    }


def test_stored_members_equal_what_numpy_load_reads(tmp_path: Path) -> None:
    path = tmp_path / "view.npz"
    np.savez(path, **arrays())
    got = read_stored(path, [*arrays(), "absent"])
    assert got is not None and set(got) == set(arrays())
    with np.load(path) as expected:
        for name in arrays():
            assert got[name].dtype == expected[name].dtype
            np.testing.assert_array_equal(got[name], expected[name])


def test_compressed_members_are_left_to_numpy(tmp_path: Path) -> None:
    path = tmp_path / "view.npz"
    np.savez_compressed(path, ids=arrays()["ids"])
    assert read_stored(path, ["ids"]) is None
    np.testing.assert_array_equal(_load_npz(path, ("ids",))["ids"], arrays()["ids"])


def test_a_truncated_member_is_an_error(tmp_path: Path) -> None:
    path = tmp_path / "view.npz"
    np.savez(path, weights=arrays()["weights"], ids=arrays()["ids"])
    data = path.read_bytes()
    # cut inside the last member's data but keep the zip directory readable
    directory = data.rfind(b"PK\x01\x02", 0, data.rfind(b"PK\x01\x02"))
    path.write_bytes(data[: directory - 4000] + data[directory:])
    with pytest.raises(ValueError, match="ids.npy"):
        read_stored(path, ["ids"])


def test_state_errors_name_the_file(tmp_path: Path) -> None:
    path = tmp_path / "3.npz"
    path.write_bytes(b"not a zip")
    with pytest.raises(InputError, match="3.npz: cannot read saved state"):
        _load_npz(path, ("ids",))
    np.savez(path, ids=arrays()["ids"], counts=arrays()["counts"], offsets=np.arange(3))
    with pytest.raises(InputError, match="missing arrays: weights"):
        _load_npz(path, ("ids", "weights"))
    loaded = _load_npz(path, ("ids",), either=("counts", "offsets"))
    assert sorted(loaded) == ["counts", "ids"], "only the first of either is kept"
