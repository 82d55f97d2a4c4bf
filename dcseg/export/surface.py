"""Object meshes from a fused TSDF: marching cubes, objects from the labelled Gaussians,
decimation, vertex colours.

Each vertex of the scene surface takes the object most of its :data:`NEIGHBOURS` nearest
Gaussians (within :data:`REACH_VOXELS` voxels) belong to; -1 when none is that close or most
belong to no object. A triangle takes the label two of its vertices share (else its first
vertex's). Labelling by the Gaussians, not by per-view instance maps, keeps the meshes
consistent with the Gaussian exports and needs nothing but the labelled scene. Each object's
triangles are decimated to ``max_faces`` (quadric error, ``fast-simplification``), then
coloured from that object's own Gaussians (their DC colour, or the palette colour).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import fast_simplification
import mcubes
import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from dcseg.export.tsdf import Volume, observed_faces

NEIGHBOURS = 8
REACH_VOXELS = 3.0
ORIENTATION_SAMPLES = 20_000
_FAR = -2  # a neighbour slot beyond the reach (casts no vote)


@dataclass(frozen=True)
class Surface:
    """A triangle mesh in world coordinates, labelled per vertex and per face."""

    vertices: NDArray[np.float64]
    faces: NDArray[np.int64]
    vertex_ids: NDArray[np.int64]
    face_ids: NDArray[np.int64]


@dataclass(frozen=True)
class ObjectMesh:
    """One object's mesh (world coordinates) with ``[V, 3]`` uint8 vertex colours."""

    instance: int
    vertices: NDArray[np.float64]
    faces: NDArray[np.int64]
    colours: NDArray[np.uint8]


def extract(volume: Volume) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Marching cubes at the zero level; ``(world vertices, faces)`` over observed cells only,
    wound counter-clockwise seen from the cameras' side (normals point out of surfaces)."""
    vertices, faces = mcubes.marching_cubes(volume.tsdf, 0.0)
    faces = observed_faces(volume, vertices, np.asarray(faces, np.int64))
    if len(faces) and _points_inward(volume, vertices, faces):
        faces = faces[:, ::-1]
    used, inverse = np.unique(faces, return_inverse=True)  # drop vertices of dropped faces
    return volume.to_world(vertices[used]), np.ascontiguousarray(inverse.reshape(-1, 3))


def _points_inward(volume: Volume, vertices: NDArray[Any], faces: NDArray[Any]) -> bool:
    """Whether face normals point against the TSDF gradient (towards negative, inside), judged
    on up to :data:`ORIENTATION_SAMPLES` faces by central differences at their cells."""
    step = max(1, len(faces) // ORIENTATION_SAMPLES)
    faces = faces[::step]
    top = np.array(volume.tsdf.shape) - 2
    idx = np.clip(np.round(vertices[faces].mean(axis=1)).astype(np.int64), 1, top)
    i, j, k = idx.T
    t = volume.tsdf
    grad = np.stack(
        [t[i + 1, j, k] - t[i - 1, j, k], t[i, j + 1, k] - t[i, j - 1, k],
         t[i, j, k + 1] - t[i, j, k - 1]], axis=1,
    )  # fmt: skip
    a, b, c = (vertices[faces[:, n]] for n in range(3))
    normals = np.cross(b - a, c - a)
    return float(np.sum(np.einsum("ij,ij->i", normals, grad))) < 0


def label_surface(
    vertices: NDArray[np.float64],
    faces: NDArray[np.int64],
    means: NDArray[Any],
    ids: NDArray[Any],
    reach: float,
) -> Surface:
    """Label every vertex by its nearest Gaussians' objects, every face by its vertices."""
    k = min(NEIGHBOURS, len(means))
    _, nearest = cKDTree(means).query(vertices, k=k, distance_upper_bound=reach)
    nearest = np.asarray(nearest).reshape(len(vertices), k)
    padded = np.concatenate([np.asarray(ids, np.int64), [_FAR]])  # index len(means) = too far
    votes = padded[nearest]
    counts = (votes[:, :, None] == votes[:, None, :]).sum(axis=2)
    counts[votes == _FAR] = 0
    best = votes[np.arange(len(votes)), counts.argmax(axis=1)]
    vertex_ids = np.where(best == _FAR, -1, best)
    a, b, c = (vertex_ids[faces[:, i]] for i in range(3))
    face_ids = np.where((a == b) | (a == c), a, np.where(b == c, b, a))
    return Surface(vertices, faces, vertex_ids, face_ids)


def object_mesh(surface: Surface, instance: int, max_faces: int) -> tuple[Any, Any] | None:
    """``(vertices, faces)`` of one object, decimated to ``max_faces``; None when it has none."""
    faces = surface.faces[surface.face_ids == instance]
    if len(faces) == 0:
        return None
    used, inverse = np.unique(faces, return_inverse=True)
    vertices, faces = surface.vertices[used], inverse.reshape(-1, 3)
    if len(faces) > max_faces:
        vertices, faces = fast_simplification.simplify(
            vertices, faces.astype(np.int32), target_count=max_faces
        )
    return np.asarray(vertices, np.float64), np.asarray(faces, np.int64)


def vertex_colours(
    vertices: NDArray[np.float64], means: NDArray[Any], rgb: NDArray[np.uint8]
) -> NDArray[np.uint8]:
    """Colour of each vertex: the mean colour of its 4 nearest Gaussians (``means``, ``rgb``)."""
    k = min(4, len(means))
    _, nearest = cKDTree(means).query(vertices, k=k)
    nearest = np.asarray(nearest).reshape(len(vertices), k)
    out: NDArray[np.uint8] = np.round(rgb[nearest].astype(np.float64).mean(axis=1)).astype(np.uint8)
    return out
