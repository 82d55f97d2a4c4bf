"""Build a furnished room in a pybullet client and describe every instance in it.

The world is z-up, in metres, with the floor's top at z = 0 and the room centred on the origin.
Objects are pybullet's textured example meshes, placed on the floor, on tables or in trays at
seeded positions without interpenetration (footprints are kept apart in 2D on each surface).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dcseg.synth.catalogue import (
    HALF_PI,
    OBJECTS,
    ROOM_HALF,
    TABLES,
    WALL_HEIGHT,
    ObjectSpec,
)
from dcseg.synth.textures import wallpaper, wood_floor


@dataclass(frozen=True)
class SceneInstance:
    """One object instance of the synthetic room.

    Attributes:
        id: instance id, unique, starting at 1 (0 is "none" in instance PNGs).
        class_name: vocabulary name.
        kind: ``structure`` (walls, floor), ``furniture`` (tables) or ``object``.
        mesh: the mesh or primitive it was built from.
        position: ``(x, y, z)`` of its base (bottom centre) in world metres.
        yaw: rotation about z in radians.
        support: id of the instance it stands on, 0 for none.
        body: the pybullet body id (valid only in the client that built it).
    """

    id: int
    class_name: str
    kind: str
    mesh: str
    position: tuple[float, float, float]
    yaw: float
    support: int
    body: int

    def record(self) -> dict[str, Any]:
        """A JSON-friendly description (without the pybullet body id)."""
        return {
            "id": self.id,
            "class": self.class_name,
            "kind": self.kind,
            "mesh": self.mesh,
            "position": [round(v, 4) for v in self.position],
            "yaw": round(self.yaw, 4),
            "support": self.support,
        }


@dataclass
class _Surface:
    """A horizontal rectangle objects can stand on, with the 2D boxes already taken."""

    owner: int
    kind: str
    bounds: tuple[float, float, float, float]
    z: float
    taken: list[tuple[float, float, float, float]] = field(default_factory=list)


@dataclass
class _Builder:
    client: int
    rng: np.random.Generator
    data: Path
    texture_dir: Path
    instances: list[SceneInstance] = field(default_factory=list)
    surfaces: list[_Surface] = field(default_factory=list)

    def add(self, class_name: str, kind: str, mesh: str, pose: tuple[Any, ...]) -> SceneInstance:
        position, yaw, support, body = pose
        inst = SceneInstance(
            len(self.instances) + 1, class_name, kind, mesh, position, yaw, support, body
        )
        self.instances.append(inst)
        return inst


def build_scene(client: int, rng: np.random.Generator, texture_dir: Path) -> list[SceneInstance]:
    """Build floor, walls, tables and objects in ``client`` and return the instance table.

    Args:
        client: a connected pybullet physics client id (DIRECT mode).
        rng: seeded generator for every placement, count and colour choice.
        texture_dir: an existing folder for the generated texture images.

    Returns:
        The instances, ids 1..N in creation order.
    """
    import pybullet_data

    builder = _Builder(client, rng, Path(pybullet_data.getDataPath()), texture_dir)
    _add_room(builder)
    _add_tables(builder)
    for spec in OBJECTS:
        for _ in range(int(rng.integers(spec.count[0], spec.count[1] + 1))):
            _add_object(builder, spec)
    return builder.instances


def _texture(builder: _Builder, name: str, image: NDArray[np.uint8]) -> int:
    import cv2
    import pybullet as p

    path = builder.texture_dir / f"{name}.png"
    cv2.imwrite(str(path), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
    return int(p.loadTexture(str(path), physicsClientId=builder.client))


_QUAD_OBJ = """v {0} {1} {2}
v {3} {4} {5}
v {6} {7} {8}
v {9} {10} {11}
vt 0 0
vt 1 0
vt 1 1
vt 0 1
f 1/1 2/2 3/3
f 1/1 3/3 4/4
f 1/1 3/3 2/2
f 1/1 4/4 3/3
"""


def _quad_body(builder: _Builder, name: str, corners: list[list[float]], texture: int) -> int:
    """A double-sided textured quad (corners counter-clockwise from the texture's bottom-left).

    A generated OBJ is used because pybullet's box primitive maps only part of a texture onto
    each face, which leaves large walls almost untextured.
    """
    import pybullet as p

    path = builder.texture_dir / f"{name}.obj"
    path.write_text(_QUAD_OBJ.format(*[c for corner in corners for c in corner]))
    cid = builder.client
    shape = p.createVisualShape(p.GEOM_MESH, fileName=str(path), physicsClientId=cid)
    body = int(p.createMultiBody(0, -1, shape, physicsClientId=cid))
    p.changeVisualShape(body, -1, textureUniqueId=texture, physicsClientId=cid)
    return body


def _add_room(builder: _Builder) -> None:
    """Floor (one instance, a surface) and four walls (one instance each)."""
    rx, ry, h = ROOM_HALF[0], ROOM_HALF[1], WALL_HEIGHT
    floor_tex = _texture(builder, "floor", wood_floor(builder.rng, 512))
    corners = [[-rx, -ry, 0.0], [rx, -ry, 0.0], [rx, ry, 0.0], [-rx, ry, 0.0]]
    body = _quad_body(builder, "floor", corners, floor_tex)
    floor = builder.add("floor", "structure", "quad", ((0.0, 0.0, 0.0), 0.0, 0, body))
    builder.surfaces.append(_Surface(floor.id, "floor", (-rx, rx, -ry, ry), 0.0))
    walls = [((-rx, ry), (rx, ry)), ((rx, -ry), (-rx, -ry)), ((rx, ry), (rx, -ry))]
    walls.append(((-rx, -ry), (-rx, ry)))
    for i, ((x0, y0), (x1, y1)) in enumerate(walls):
        length = math.hypot(x1 - x0, y1 - y0)
        image = wallpaper(builder.rng, int(256 * length / h), 256)
        tex = _texture(builder, f"wall{i}", image)
        corners = [[x0, y0, 0.0], [x1, y1, 0.0], [x1, y1, h], [x0, y0, h]]
        body = _quad_body(builder, f"wall{i}", corners, tex)
        centre = ((x0 + x1) / 2, (y0 + y1) / 2, 0.0)
        yaw = math.atan2(y1 - y0, x1 - x0)
        builder.add("wall", "structure", "quad", (centre, yaw, 0, body))


def _add_tables(builder: _Builder) -> None:
    """Two tables of different shapes on the floor, apart from each other."""
    import pybullet as p

    floor = builder.surfaces[0]
    for urdf, scale, (sx, sy), top in TABLES:
        yaw = float(builder.rng.choice([0.0, HALF_PI]))
        hx, hy = (sx / 2, sy / 2) if yaw == 0.0 else (sy / 2, sx / 2)
        for _ in range(200):
            x, y = builder.rng.uniform(-1.3, 1.3), builder.rng.uniform(-0.9, 0.9)
            box = (x - hx, x + hx, y - hy, y + hy)
            if _free(floor, box, margin=0.35):
                break
        floor.taken.append(box)
        quat = p.getQuaternionFromEuler([0, 0, yaw])
        body = int(
            p.loadURDF(
                str(builder.data / urdf),
                [x, y, 0.0],
                quat,
                globalScaling=scale,
                useFixedBase=True,
                physicsClientId=builder.client,
            )
        )
        pose = ((float(x), float(y), 0.0), yaw, floor.owner, body)
        inst = builder.add("table", "furniture", urdf, pose)
        z = top * scale
        builder.surfaces.append(_Surface(inst.id, "table", (box[0], box[1], box[2], box[3]), z))


def _free(surface: _Surface, box: tuple[float, float, float, float], margin: float) -> bool:
    """Whether ``box`` (xmin, xmax, ymin, ymax) stays inside the surface and clear of others."""
    x0, x1, y0, y1 = surface.bounds
    if box[0] < x0 or box[1] > x1 or box[2] < y0 or box[3] > y1:
        return False
    for t in surface.taken:
        if box[0] < t[1] + margin and t[0] < box[1] + margin:
            if box[2] < t[3] + margin and t[2] < box[3] + margin:
                return False
    return True


@functools.lru_cache(maxsize=32)
def _obj_vertices(path: str) -> NDArray[np.float64]:
    """The ``v`` lines of an OBJ file as an ``[N, 3]`` array."""
    with open(path, encoding="utf-8", errors="replace") as fh:
        rows = [line.split()[1:4] for line in fh if line.startswith("v ")]
    return np.asarray(rows, dtype=np.float64)


def _upright_mesh(builder: _Builder, spec: ObjectSpec) -> tuple[NDArray[np.float64], float, float]:
    """Offset that puts the mesh's bottom centre at the origin, its xy radius and height."""
    from scipy.spatial.transform import Rotation

    verts = _obj_vertices(str(builder.data / spec.mesh)) * np.asarray(spec.scale)
    verts = Rotation.from_euler("xyz", spec.upright).apply(verts)
    lo, hi = verts.min(axis=0), verts.max(axis=0)
    base = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]])
    radius = float(np.linalg.norm((verts - base)[:, :2], axis=1).max())
    return -base, radius, float(hi[2] - lo[2])


def _add_object(builder: _Builder, spec: ObjectSpec) -> None:
    """Place one instance of ``spec`` on a free spot of an allowed surface (skipped if none)."""
    offset, radius, height = _upright_mesh(builder, spec)
    spot = _find_spot(builder, spec, radius)
    if spot is None:
        return
    surface, x, y = spot
    surface.taken.append((x - radius, x + radius, y - radius, y + radius))
    yaw = float(builder.rng.uniform(-math.pi, math.pi))
    tint = spec.tints[int(builder.rng.integers(len(spec.tints)))]
    body = _mesh_body(builder, spec, offset, (x, y, surface.z, yaw), tint)
    pose = ((float(x), float(y), surface.z), yaw, surface.owner, body)
    inst = builder.add(spec.class_name, "object", spec.mesh, pose)
    if spec.class_name == "tray":
        inner = 0.41 * spec.scale[0]
        bounds = (x - inner, x + inner, y - inner, y + inner)
        builder.surfaces.append(_Surface(inst.id, "tray", bounds, surface.z + 0.02 * spec.scale[2]))


def _find_spot(
    builder: _Builder, spec: ObjectSpec, radius: float
) -> tuple[_Surface, float, float] | None:
    """A random free position for a footprint of ``radius`` on an allowed surface."""
    surfaces = [s for s in builder.surfaces if s.kind in spec.supports]
    order = builder.rng.permutation(len(surfaces))
    for index in order:
        surface = surfaces[int(index)]
        x0, x1, y0, y1 = surface.bounds
        if surface.kind == "floor":
            x0, x1, y0, y1 = -1.6, 1.6, -1.3, 1.3
        for _ in range(40):
            x = float(builder.rng.uniform(x0 + radius, x1 - radius)) if x1 - x0 > 2 * radius else x0
            y = float(builder.rng.uniform(y0 + radius, y1 - radius)) if y1 - y0 > 2 * radius else y0
            if _free(surface, (x - radius, x + radius, y - radius, y + radius), margin=0.02):
                return surface, x, y
    return None


def _mesh_body(
    builder: _Builder,
    spec: ObjectSpec,
    offset: NDArray[np.float64],
    pose: tuple[float, float, float, float],
    tint: tuple[float, float, float, float],
) -> int:
    """Create a visual-only body for ``spec`` with its bottom centre at ``pose`` (x, y, z, yaw)."""
    import pybullet as p

    cid = builder.client
    shape = p.createVisualShape(
        p.GEOM_MESH,
        fileName=str(builder.data / spec.mesh),
        meshScale=list(spec.scale),
        rgbaColor=list(tint),
        visualFramePosition=[float(v) for v in offset],
        visualFrameOrientation=p.getQuaternionFromEuler(list(spec.upright)),
        physicsClientId=cid,
    )
    x, y, z, yaw = pose
    quat = p.getQuaternionFromEuler([0.0, 0.0, yaw])
    return int(p.createMultiBody(0, -1, shape, [x, y, z], quat, physicsClientId=cid))
