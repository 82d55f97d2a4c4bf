"""frame.json: the up axis from camera poses and the turn to glTF's Y-up."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from dcseg.export import export_run
from dcseg.export.frame import describe_frame, estimate_up, rotation_to_y_up, snap_axis
from tests.scenes.analytic import look_at


def _orbit(up_tilt: float = 0.0) -> np.ndarray:
    """Cameras orbiting the origin, world +z up, the whole rig tilted about x."""
    c, s = np.cos(up_tilt), np.sin(up_tilt)
    tilt = np.array([[1, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1]], np.float64)
    poses = []
    for a in np.linspace(0, 2 * np.pi, 8, endpoint=False):
        eye = np.array([2 * np.cos(a), 2 * np.sin(a), 1.2])
        poses.append(tilt @ look_at(eye, np.zeros(3)))
    return np.stack(poses)


def test_level_cameras_give_world_z_up_and_the_standard_turn() -> None:
    up = estimate_up(_orbit())
    assert up is not None and snap_axis(up) == "+z"
    body = describe_frame(_orbit(), ["scene.glb"])
    turn = np.array(body["to_gltf"]["matrix"])
    assert np.array_equal(turn[:3, :3], [[1, 0, 0], [0, 0, 1], [0, -1, 0]])
    assert body["world"]["up"] == [0.0, 0.0, 1.0] and body["units"] == "metres"


@pytest.mark.parametrize("tilt", [0.5, 1.2, np.pi])
def test_a_tilted_rig_is_turned_upright(tilt: float) -> None:
    poses = _orbit(tilt)
    up = estimate_up(poses)
    assert up is not None
    expected = np.array([0.0, -np.sin(tilt), np.cos(tilt)])
    assert np.allclose(up, expected, atol=1e-6)
    turn = rotation_to_y_up(up)
    assert np.allclose(turn[:3, :3] @ up, [0, 1, 0], atol=1e-9)
    assert np.allclose(turn[:3, :3] @ turn[:3, :3].T, np.eye(3), atol=1e-9)
    assert np.linalg.det(turn[:3, :3]) == pytest.approx(1.0)


def test_no_poses_leave_the_frame_unturned() -> None:
    body = describe_frame(None, [])
    assert body["world"]["up"] is None and body["to_gltf"]["matrix"] == np.eye(4).tolist()


def test_every_export_writes_the_frame(run: Path, tmp_path: Path) -> None:
    export_run(run, tmp_path, "splat", instances=[1])
    body = json.loads((tmp_path / "frame.json").read_text())
    assert body["world"]["up_axis"] == "+z"
    assert body["world"]["up_source"] == "mean camera -y axis over 8 views"
