"""What the synthetic room is made of: the vocabulary, room size, tables and object classes."""

from __future__ import annotations

import math
from dataclasses import dataclass

ROOM_HALF = (2.6, 2.1)
"""Half extents (x, y) of the room's floor in metres."""
WALL_HEIGHT = 2.4
VOCABULARY = (
    "wall",
    "floor",
    "table",
    "tray",
    "duck",
    "teddy",
    "mug",
    "ball",
    "block",
    "lego",
    "domino",
    "bowl",
)
"""Class names; ``bowl`` never occurs in the ground truth (a confusion target only)."""
RARE_CLASSES = ("lego", "domino")


HALF_PI = math.pi / 2


@dataclass(frozen=True)
class ObjectSpec:
    """How to instantiate one class of small object from a pybullet_data mesh.

    Attributes:
        class_name: vocabulary name.
        mesh: OBJ path relative to ``pybullet_data.getDataPath()``.
        scale: per-axis mesh scale.
        upright: XYZ Euler angles (radians) that stand the mesh up in a z-up world.
        count: inclusive range of the number of instances.
        supports: classes it may stand on (``floor``, ``table``, ``tray``).
        tints: RGBA colours to choose from per instance (white keeps the mesh texture).
    """

    class_name: str
    mesh: str
    scale: tuple[float, float, float]
    upright: tuple[float, float, float]
    count: tuple[int, int]
    supports: tuple[str, ...]
    tints: tuple[tuple[float, float, float, float], ...] = ((1.0, 1.0, 1.0, 1.0),)


OBJECTS = (
    ObjectSpec("tray", "tray/tray_textured.obj", (0.32,) * 3, (0, 0, 0), (1, 2), ("table",)),
    ObjectSpec(
        "teddy",
        "teddy2_VHACD_CHs.obj",
        (0.3,) * 3,
        (HALF_PI, 0, 0),
        (2, 2),
        ("floor", "table"),
        ((0.65, 0.45, 0.3, 1), (0.9, 0.8, 0.6, 1), (0.5, 0.35, 0.35, 1)),
    ),
    ObjectSpec("ball", "soccerball.obj", (0.22,) * 3, (0, 0, 0), (2, 2), ("floor",)),
    ObjectSpec(
        "duck", "duck.obj", (0.09,) * 3, (HALF_PI, 0, 0), (2, 3), ("table", "tray", "floor")
    ),
    ObjectSpec(
        "mug",
        "objects/mug.obj",
        (1.3,) * 3,
        (0, 0, 0),
        (2, 3),
        ("table", "tray"),
        ((0.9, 0.2, 0.2, 1), (0.2, 0.4, 0.85, 1), (0.95, 0.95, 0.9, 1), (0.2, 0.7, 0.3, 1)),
    ),
    ObjectSpec(
        "block", "jenga/jenga.obj", (0.16, 0.05, 0.035), (0, 0, 0), (2, 3), ("table", "floor")
    ),
    ObjectSpec(
        "lego",
        "lego/lego.obj",
        (0.15,) * 3,
        (HALF_PI, 0, 0),
        (1, 1),
        ("table", "tray"),
        ((1.0, 1.0, 0.4, 1),),
    ),
    ObjectSpec("domino", "domino/domino.obj", (1.6,) * 3, (0, 0, 0), (1, 1), ("table", "tray")),
)

TABLES = (
    ("table/table.urdf", 0.8, (1.2, 0.8), 0.625),
    ("table_square/table_square.urdf", 1.1, (0.66, 0.66), 0.64),
)
"""(urdf, global scale, top size at that scale, top height per unit scale)."""
