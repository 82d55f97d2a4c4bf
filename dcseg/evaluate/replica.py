"""Replica's 51 evaluation classes and their head/common/tail split (method doc §7.2).

From OpenNeRF's evaluation (``opennerf/opennerf:datasets/replica.py``): the reduced class index
is the position in :data:`REPLICA_CLASSES`; the split is by index, 0-16 head, 17-33 common,
34-50 tail. Raw Replica ids -1, -2 and 256 are ignored in ground truth.
"""

from __future__ import annotations

from types import MappingProxyType
from typing import Any

import numpy as np
from numpy.typing import NDArray

REPLICA_CLASSES: tuple[tuple[str, int], ...] = (
    ("wall", 93),
    ("ceiling", 31),
    ("floor", 40),
    ("chair", 20),
    ("blinds", 12),
    ("sofa", 76),
    ("table", 80),
    ("rug", 98),
    ("window", 97),
    ("lamp", 47),
    ("door", 37),
    ("pillow", 61),
    ("bench", 8),
    ("tv-screen", 87),
    ("cabinet", 18),
    ("pillar", 60),
    ("blanket", 11),
    ("tv-stand", 88),
    ("cushion", 29),
    ("bin", 10),
    ("vent", 92),
    ("bed", 7),
    ("stool", 78),
    ("picture", 59),
    ("indoor-plant", 44),
    ("desk", 34),
    ("comforter", 26),
    ("nightstand", 54),
    ("shelf", 71),
    ("vase", 91),
    ("plant-stand", 63),
    ("basket", 3),
    ("plate", 64),
    ("monitor", 52),
    ("pipe", 62),
    ("panel", 56),
    ("desk-organizer", 35),
    ("wall-plug", 95),
    ("book", 13),
    ("box", 15),
    ("clock", 22),
    ("sculpture", 70),
    ("tissue-paper", 83),
    ("camera", 17),
    ("tablet", 82),
    ("pot", 65),
    ("bottle", 14),
    ("candle", 19),
    ("bowl", 16),
    ("cloth", 23),
    ("switch", 79),
)
"""``(name, raw Replica id)`` per reduced class index 0..50."""

REPLICA_CLASS_NAMES: tuple[str, ...] = tuple(name for name, _ in REPLICA_CLASSES)
"""The 51 class names in reduced-index order (the vocabulary for Replica evaluation)."""

REPLICA_RAW_IDS: tuple[int, ...] = tuple(raw for _, raw in REPLICA_CLASSES)
"""Raw Replica semantic id per reduced class index."""

REPLICA_IGNORED_RAW_IDS: tuple[int, ...] = (-1, -2, 256)
"""Raw ids that the ground truth uses for unlabelled / ignored vertices."""

REPLICA_SPLIT: MappingProxyType[str, tuple[int, ...]] = MappingProxyType(
    {
        "head": tuple(range(0, 17)),
        "common": tuple(range(17, 34)),
        "tail": tuple(range(34, 51)),
    }
)
"""Head/common/tail class indices (17 each, by list order)."""


def replica_labels_from_raw(raw: NDArray[Any]) -> NDArray[np.int64]:
    """Map raw Replica semantic ids ``[P]`` to reduced class indices ``[P]``.

    Ids outside the 51-class table (including the ignored -1, -2, 256) map to -1 (ignored).
    """
    raw = np.asarray(raw, dtype=np.int64)
    lut = np.full(max(REPLICA_RAW_IDS) + 1, -1, dtype=np.int64)
    lut[list(REPLICA_RAW_IDS)] = np.arange(len(REPLICA_RAW_IDS))
    inside = (raw >= 0) & (raw < len(lut))
    return np.where(inside, lut[np.where(inside, raw, 0)], -1)
