from dataclasses import replace
from typing import Any

import numpy as np
import pytest
from numpy.typing import NDArray

from dcseg.assign import rings
from dcseg.assign.config import AssignConfig
from dcseg.assign.rings import release_rings

UP = np.array([0.0, 0.0, 1.0])
CFG = AssignConfig(ring_plane_tol=0.015, ring_radius=0.1, ring_min_cosine=0.8)
Scene = tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int64]]
"""Centres, disc normals and cluster per Gaussian."""
TABLE, OBJECT, TRAY, POSTER = 0, 1, 2, 3
"""Class ids of the scenes below (wall = 4 is stuff in some tests)."""


def _grid(
    x0: float, x1: float, y0: float, y1: float, z: float, step: float = 0.02
) -> NDArray[np.float64]:
    xs, ys = np.meshgrid(np.arange(x0, x1, step), np.arange(y0, y1, step))
    out: NDArray[np.float64] = np.c_[xs.ravel(), ys.ravel(), np.full(xs.size, z)]
    return out


def _scene(
    parts: list[tuple[NDArray[np.float64], NDArray[np.float64], int]], seed: int = 0
) -> Scene:
    """Centres (scattered 3 mm about their surfaces), disc normals and clusters of parts."""
    rng = np.random.default_rng(seed)
    means = np.concatenate([p for p, _, _ in parts])
    means = means + rng.normal(0.0, 0.003, means.shape)
    normals = np.concatenate([np.tile(n, (len(p), 1)) for p, n, _ in parts])
    labels = np.concatenate([np.full(len(p), k) for p, _, k in parts])
    return means, normals, labels


def _cylinder(
    cx: float, cy: float, radius: float, height: float
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Side of a standing cylinder from 2 cm above the table: points and outward normals."""
    t, z = np.meshgrid(np.linspace(0, 2 * np.pi, 24, endpoint=False), np.arange(0.02, height, 0.02))
    side = np.c_[np.cos(t.ravel()), np.sin(t.ravel()), np.zeros(t.size)]
    return np.c_[np.array([cx, cy]) + radius * side[:, :2], z.ravel()], side


def _mug_scene() -> tuple[
    NDArray[np.float64], NDArray[np.float64], NDArray[np.int64], NDArray[np.bool_]
]:
    """A table (cluster 0) and a mug (cluster 1) whose cluster took the table round its base
    (a 5 cm band): the band is returned as a mask. No Gaussian lies under the mug."""
    table = _grid(0.0, 1.0, 0.0, 1.0, 0.0)
    off_centre = np.hypot(table[:, 0] - 0.5, table[:, 1] - 0.5)
    table = table[off_centre > 0.05]
    ring = off_centre[off_centre > 0.05] < 0.1
    side, outward = _cylinder(0.5, 0.5, 0.04, 0.12)
    means, normals, labels = _scene([(table, UP, 0), (side, UP, 1)])
    normals[len(table) :] = outward
    labels[: len(table)][ring] = 1
    band = np.zeros(len(means), dtype=bool)
    band[: len(table)] = ring
    return means, normals, labels, band


def test_the_ring_round_a_mug_goes_back_to_the_table() -> None:
    means, normals, labels, band = _mug_scene()
    out, moved = release_rings(means, normals, labels, np.array([TABLE, OBJECT]), [], CFG)
    assert moved == band.sum() > 0
    assert (out[band] == 0).all()
    assert (out[~band] == labels[~band]).all()  # the mug's side and the table stay


def test_other_objects_round_a_ring_do_not_make_it_a_tray_bottom() -> None:
    """Eight objects of another class stand 25 cm round the mug (a cluttered table): together
    they surround its ring, but they are no body of the mug's, so the ring still goes back."""
    means, normals, labels, band = _mug_scene()
    parts = [_cylinder(0.5 + 0.25 * np.cos(a), 0.5 + 0.25 * np.sin(a), 0.03, 0.1)
             for a in np.linspace(0.0, 2.0 * np.pi, 8, endpoint=False)]  # fmt: skip
    others = np.concatenate([p for p, _ in parts])
    means = np.concatenate([means, others])
    normals = np.concatenate([normals, *[n for _, n in parts]])
    labels = np.r_[labels, np.repeat(np.arange(2, 10), [len(p) for p, _ in parts])]
    classes = np.array([TABLE, OBJECT, *[TRAY] * 8])
    out, moved = release_rings(means, normals, labels, classes, [], CFG)
    assert moved == band.sum() > 0
    assert (out[: len(band)][band] == 0).all()
    assert (out[len(band) :] == labels[len(band) :]).all()  # the objects keep theirs


def test_candidates_looked_up_in_blocks_give_the_same_moves(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    means, normals, labels, _ = _mug_scene()
    classes = np.array([TABLE, OBJECT])
    whole = release_rings(means, normals, labels, classes, [], CFG)
    monkeypatch.setattr(rings, "RING_BLOCK", 7)
    blocks = release_rings(means, normals, labels, classes, [], CFG)
    assert whole[1] == blocks[1] > 0 and np.array_equal(whole[0], blocks[0])


def test_off_leaves_the_clusters_alone() -> None:
    means, normals, labels, _ = _mug_scene()
    off = replace(CFG, ring_plane_tol=0.0)
    out, moved = release_rings(means, normals, labels, np.array([TABLE, OBJECT]), [], off)
    assert moved == 0 and (out == labels).all()


def test_an_unlabelled_support_or_a_stuff_object_keeps_its_ring() -> None:
    """The table cluster is unlabelled: there is no class to give the ring. Then the mug's
    cluster is of a stuff class: stuff clusters are supports, never objects."""
    means, normals, labels, _ = _mug_scene()
    out, moved = release_rings(means, normals, labels, np.array([-1, OBJECT]), [], CFG)
    assert moved == 0 and (out == labels).all()
    out, moved = release_rings(means, normals, labels, np.array([TABLE, 4]), [4], CFG)
    assert moved == 0


def test_a_ring_off_the_plane_or_facing_elsewhere_stays() -> None:
    """Raised 4 cm (a plate's rim height), or with discs standing upright, the band is part of
    the object, not of the table's surface."""
    means, normals, labels, band = _mug_scene()
    raised = means.copy()
    raised[band, 2] += 0.04
    out, moved = release_rings(raised, normals, labels, np.array([TABLE, OBJECT]), [], CFG)
    assert moved == 0
    upright = normals.copy()
    upright[band] = [1.0, 0.0, 0.0]
    out, moved = release_rings(means, upright, labels, np.array([TABLE, OBJECT]), [], CFG)
    assert moved == 0


def test_a_tray_keeps_its_bottom_inside_its_rim() -> None:
    """A 32 cm tray's bottom lies 6 mm above the table, inside a 4 cm rim: the rim encloses it,
    so it stays the tray; the table round the tray that the tray's cluster took goes back."""
    table = _grid(0.0, 1.2, 0.0, 1.2, 0.0)
    outside = (np.abs(table[:, 0] - 0.6) > 0.17) | (np.abs(table[:, 1] - 0.6) > 0.17)
    bottom = _grid(0.45, 0.75, 0.45, 0.75, 0.006)
    t = np.linspace(0.44, 0.76, 33)  # the rim's Gaussians 1 cm apart
    edge = np.concatenate([np.c_[t, np.full(33, y)] for y in (0.44, 0.76)]
                          + [np.c_[np.full(33, x), t] for x in (0.44, 0.76)])  # fmt: skip
    rim = np.concatenate([np.c_[edge, np.full(len(edge), z)] for z in (0.02, 0.04)])
    skirt = outside & (np.abs(table[:, 0] - 0.6) < 0.22) & (np.abs(table[:, 1] - 0.6) < 0.22)
    means, normals, labels = _scene(
        [(table[outside], UP, 0), (bottom, UP, 1), (rim, np.array([1.0, 0.0, 0.0]), 1)]
    )
    labels[: outside.sum()][skirt[outside]] = 1
    out, moved = release_rings(means, normals, labels, np.array([TABLE, TRAY]), [], CFG)
    n_table = outside.sum()
    assert (out[:n_table][skirt[outside]] == 0).all()
    assert (out[n_table:] == 1).mean() > 0.97  # bottom and rim (a few by the rim may go)
    assert moved == skirt.sum() + (out[n_table:] != 1).sum()


def test_a_thin_block_keeps_its_top_face() -> None:
    """A block lying flat, its top face 1.2 cm above the table: within the plane tolerance,
    but the face sits above the table's plane as a whole, not about it as a ring does."""
    table = _grid(0.0, 1.0, 0.0, 1.0, 0.0)
    under = (np.abs(table[:, 0] - 0.5) < 0.09) & (np.abs(table[:, 1] - 0.5) < 0.04)
    top = _grid(0.42, 0.58, 0.46, 0.54, 0.012)
    means, normals, labels = _scene([(table[~under], UP, 0), (top, UP, 1)])
    unguarded = replace(CFG, ring_max_share=1.0)  # not kept as a flat object: by its rise
    out, moved = release_rings(means, normals, labels, np.array([TABLE, OBJECT]), [], unguarded)
    assert moved == 0 and (out == labels).all()


def _wall_with(piece: NDArray[np.float64]) -> Scene:
    """A wall (cluster 0, in the plane x = 0) with a flat piece on it (cluster 1)."""
    ys, zs = np.meshgrid(np.arange(0.0, 2.0, 0.02), np.arange(0.0, 2.0, 0.02))
    wall = np.c_[np.zeros(ys.size), ys.ravel(), zs.ravel()]
    keep = ~np.isin(np.round(wall, 3).view([("", float)] * 3), np.round(piece, 3).view(
        [("", float)] * 3)).ravel()  # fmt: skip
    return _scene([(wall[keep], np.array([1.0, 0.0, 0.0]), 0), (piece, np.array([1.0, 0, 0]), 1)])


def _poster() -> NDArray[np.float64]:
    ys, zs = np.meshgrid(np.arange(0.8, 1.2, 0.02), np.arange(0.8, 1.2, 0.02))
    out: NDArray[np.float64] = np.c_[np.zeros(ys.size), ys.ravel(), zs.ravel()]
    return out


def test_a_poster_flat_on_the_wall_stays_a_poster() -> None:
    means, normals, labels = _wall_with(_poster())
    out, moved = release_rings(means, normals, labels, np.array([4, POSTER]), [4], CFG)
    assert moved == 0 and (out == labels).all()


def test_a_flat_piece_beside_an_object_of_its_class_goes_back() -> None:
    """The same flat piece, with a framed picture of its class (cluster 2, standing off the
    wall) beside it: it is wall that the picture's masks took."""
    means, normals, labels = _wall_with(_poster())
    frame = np.c_[np.full(40, 0.05), np.full(40, 1.25), np.linspace(0.8, 1.2, 40)]
    means = np.concatenate([means, frame])
    normals = np.concatenate([normals, np.tile([0.0, 1.0, 0.0], (40, 1))])
    labels = np.r_[labels, np.full(40, 2)]
    classes = np.array([4, POSTER, POSTER])
    out, moved = release_rings(means, normals, labels, classes, [4], CFG)
    piece = labels == 1
    assert moved == piece.sum() and (out[piece] == 0).all()
    assert (out[labels == 2] == 2).all()


def test_flat_pieces_of_one_class_side_by_side_stay() -> None:
    """Two flat pieces of one class on the wall (a poster cut into two clusters): neither
    rises from the wall, so neither is a piece the other's masks took."""
    poster = _poster()
    means, normals, labels = _wall_with(poster)
    left = np.flatnonzero(labels == 1)[poster[:, 1] < 1.0]
    labels[left] = 2
    classes = np.array([4, POSTER, POSTER])
    out, moved = release_rings(means, normals, labels, classes, [4], CFG)
    assert moved == 0 and (out == labels).all()


def test_a_support_that_is_not_flat_gives_no_plane() -> None:
    """Discs pointing every way (a ball or a plant under the object): no plane to continue."""
    means, normals, labels, band = _mug_scene()
    rng = np.random.default_rng(1)
    table = labels == 0
    scattered = rng.normal(size=(int(table.sum()), 3))
    normals[table] = scattered / np.linalg.norm(scattered, axis=1, keepdims=True)
    out, moved = release_rings(means, normals, labels, np.array([TABLE, OBJECT]), [], CFG)
    assert moved == 0


@pytest.mark.parametrize(
    "field, value",
    [("ring_plane_tol", -0.01), ("ring_plane_tol", float("nan")), ("ring_radius", -1.0),
     ("ring_min_cosine", 1.5), ("ring_max_share", -0.1), ("ring_rounds", 0)],
)  # fmt: skip
def test_ring_settings_are_checked(field: str, value: float) -> None:
    changes: dict[str, Any] = {field: value}
    with pytest.raises(ValueError, match=field):
        AssignConfig(**changes)


def test_ring_radius_must_be_positive_when_on() -> None:
    with pytest.raises(ValueError, match="ring_radius"):
        AssignConfig(ring_plane_tol=0.01, ring_radius=0.0)
    assert AssignConfig(ring_plane_tol=0.0, ring_radius=0.0).ring_radius == 0.0


def test_rounds_do_not_climb_a_low_ramp() -> None:
    """A 30 cm ramp rising 6 cm from the floor (discs tilted 11 deg, facing up enough): its
    foot lies in the floor's plane and goes back to the floor, but later rounds measure
    against the floor's plane, not against the ramp Gaussians moved before, so nothing more
    than ``ring_plane_tol`` (and the 3 mm scatter) above the floor moves."""
    floor = _grid(0.0, 1.0, 0.0, 1.0, 0.0)
    inside = (np.abs(floor[:, 0] - 0.45) < 0.16) & (np.abs(floor[:, 1] - 0.45) < 0.16)
    ramp = _grid(0.3, 0.6, 0.3, 0.6, 0.0, step=0.01)
    ramp[:, 2] = 0.2 * (ramp[:, 0] - 0.3)
    slope = np.array([-0.2, 0.0, 1.0]) / np.hypot(0.2, 1.0)
    means, normals, labels = _scene([(floor[~inside], UP, 0), (ramp, slope, 1)])
    out, moved = release_rings(means, normals, labels, np.array([TABLE, OBJECT]), [], CFG)
    gone = (labels == 1) & (out == 0)
    assert moved == gone.sum() > 0
    assert means[gone, 2].max() < CFG.ring_plane_tol + 0.003
