"""SPZ is written in the axes its specification fixes (RUB: +y up, glTF's): the z-up test scene
read back by an independent reader (PlayCanvas splat-transform) stands upright, with its
rotations and view-dependent colour turned alike; the SH rotation itself is checked too."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from dcseg.export import export_run
from dcseg.export.axes import quat_multiply, sh_basis, sh_rotation, turned
from dcseg.io.splat_table import SplatTable, read_splat_table
from tests.dcseg.export.node_tools import splat_table_csv
from tests.scenes.runs import BOX

Z_UP_TO_Y_UP = np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]])  # world z -> y, world y -> -z
C1 = 0.4886025119029199  # the degree-1 constant of the KHR_gaussian_splatting appendix


def _scene_order(run: Path, sidecar: Path) -> np.ndarray:
    ids = read_splat_table(run / "scene_labelled.ply").ints["instance_id"]
    table = json.loads(sidecar.read_text())
    rows = [np.flatnonzero(ids == r["id"]) for r in table["instances"]]
    return np.concatenate([*rows, np.flatnonzero(ids < 0)])


def _degree_one_colour(coeffs: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Colour offset of degree-1 SH ``[N, 3 coeffs, 3 channels]`` seen along ``dirs [N, 3]``."""
    x, y, z = (dirs[:, i : i + 1] for i in range(3))
    out: np.ndarray = C1 * (-y * coeffs[:, 0] + z * coeffs[:, 1] - x * coeffs[:, 2])
    return out


@pytest.fixture(scope="module")
def spz(run: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("spz")
    export_run(run, out, "spz")
    return out


def test_frame_json_says_the_scene_is_z_up_and_how_spz_was_turned(spz: Path) -> None:
    frame = json.loads((spz / "frame.json").read_text())
    assert frame["world"]["up_axis"] == "+z"
    assert np.allclose(np.asarray(frame["to_gltf"]["matrix"])[:3, :3], Z_UP_TO_Y_UP)
    assert "scene.spz" in " ".join(frame["to_gltf"]["applied_in"])


def test_an_independent_reader_sees_the_spz_scene_upright(
    run: Path, spz: Path, tmp_path: Path
) -> None:
    cols = splat_table_csv(spz / "scene.spz", tmp_path / "spz.csv")
    source = read_splat_table(run / "scene_labelled.ply")
    src = source.take(_scene_order(run, spz / "instances.spz.json"))
    means = np.stack([cols["x"], cols["y"], cols["z"]], axis=1)
    assert np.abs(means - src.means @ Z_UP_TO_Y_UP.T).max() <= 1 / 4096
    box = src.ints["instance_id"] == BOX
    assert means[box, 1].max() == pytest.approx(0.4, abs=1e-3)  # the box's top is up (+y)
    assert np.abs(means[~box, 1]).max() < 1e-3  # the floor lies in y = 0
    wxyz = np.stack([cols[f"rot_{i}"] for i in range(4)], axis=1)
    got = Rotation.from_quat(wxyz[:, [1, 2, 3, 0]]).as_matrix()
    want = Z_UP_TO_Y_UP @ Rotation.from_quat(src.quats[:, [1, 2, 3, 0]]).as_matrix()
    assert np.abs(got - want).max() < 0.01
    rest = np.stack([cols[f"f_rest_{i}"] for i in range(9)], axis=1).reshape(-1, 3, 3)
    coeffs = rest.transpose(0, 2, 1)  # PLY's channel-major f_rest -> [N, coeff, channel]
    rng = np.random.default_rng(0)
    dirs = rng.normal(size=(len(src), 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    before = _degree_one_colour(src.sh[:, 1:4], dirs)
    after = _degree_one_colour(coeffs, dirs @ Z_UP_TO_Y_UP.T)  # the same ray, turned
    assert np.abs(after - before).max() < 3 * C1 * 0.5 / 128 + 1e-4  # 8-bit SH quantisation


@pytest.mark.parametrize("degree", [1, 2, 3])
def test_turned_gaussians_look_the_same_from_turned_directions(degree: int) -> None:
    rng = np.random.default_rng(degree)
    rot = Rotation.random(random_state=degree).as_matrix()
    n, k = 50, (degree + 1) ** 2
    table = SplatTable(
        rng.normal(size=(n, 3)).astype(np.float32),
        rng.normal(size=(n, 4)).astype(np.float32),
        rng.normal(size=(n, 3)).astype(np.float32),
        rng.normal(size=n).astype(np.float32),
        rng.normal(size=(n, k, 3)).astype(np.float32),
    )
    out = turned(table, rot)
    dirs = rng.normal(size=(n, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    before = np.einsum("nk,nkc->nc", sh_basis(dirs, degree), table.sh)
    after = np.einsum("nk,nkc->nc", sh_basis(dirs @ rot.T, degree), out.sh)
    assert np.abs(after - before).max() < 1e-4
    assert np.allclose(out.means, table.means @ rot.T, atol=1e-5)
    assert np.array_equal(out.log_scales, table.log_scales)
    assert np.allclose(sh_rotation(rot, degree)[0], np.eye(k)[0])  # DC never changes
    unit = table.quats / np.linalg.norm(table.quats, axis=1, keepdims=True)
    got = Rotation.from_quat(np.asarray(out.quats)[:, [1, 2, 3, 0]]).as_matrix()
    want = rot @ Rotation.from_quat(unit[:, [1, 2, 3, 0]]).as_matrix()
    assert np.abs(got - want).max() < 1e-5
    assert quat_multiply(np.array([1.0, 0, 0, 0]), unit).shape == (n, 4)
