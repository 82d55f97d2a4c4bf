"""The working resolution and keyframes of a run, chosen from a capture's listing.

:func:`plan_capture` applies a :class:`~dcseg.config.FrameBudget` to the frames a layout
listed (after ``stride``/``max_frames``), before any image is decoded:

1. **Resolution.** The frames are downscaled by the smallest integer factor ``f`` that brings
   their longer side to at most ``max_side`` (``f = ceil(longer side / max_side)``); the working
   size is ``round(width / f) x round(height / f)``. An integer factor keeps the area filter a
   plain block average and lets per-view outputs go back to the capture's resolution exactly
   (nearest neighbour, every working pixel covers an ``f x f`` block).
2. **Keyframes by camera motion.** The first frame is a keyframe; a later frame is one when its
   camera moved at least ``min_translation`` metres or turned at least ``min_rotation_deg``
   degrees since the last keyframe (frames whose pose is not finite are kept, so that reading
   them reports the problem).
3. **Cap.** When more than ``max_keyframes`` keyframes remain, ``max_keyframes`` of them are kept,
   evenly spaced over the sequence (the first and the last are always among them).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dcseg.config import FrameBudget
from dcseg.io.folders import FrameSelection

__all__ = ["CaptureMeta", "CapturePlan", "downscale_factor", "keyframes", "plan_capture"]


@dataclass(frozen=True)
class CaptureMeta:
    """What planning needs of a capture, known without decoding its images.

    Attributes:
        names: frame names in capture order (after ``stride``/``max_frames``).
        c2w: ``[F, 4, 4]`` camera-to-world poses, in the same order.
        size: ``(width, height)`` of the frames as read (the output resolution).
    """

    names: tuple[str, ...]
    c2w: NDArray[np.float64]
    size: tuple[int, int]


@dataclass(frozen=True)
class CapturePlan:
    """The frames a run reads and the resolution it trains at.

    Attributes:
        budget: the budget the plan follows.
        output_size: ``(width, height)`` of per-view outputs (the capture's resolution).
        size: ``(width, height)`` the frames are read and trained at.
        factor: the integer downscale factor between the two (1 = native).
        listed: the names of every frame the capture lists (after ``stride``/``max_frames``).
        moved: how many frames the motion rule kept (before the ``max_keyframes`` cap).
        frames: indices into ``listed`` of the frames read, in capture order.
    """

    budget: FrameBudget
    output_size: tuple[int, int]
    size: tuple[int, int]
    factor: int
    listed: tuple[str, ...]
    moved: int
    frames: tuple[int, ...]

    @property
    def names(self) -> tuple[str, ...]:
        """The names of the frames read."""
        return tuple(self.listed[i] for i in self.frames)

    def selection(self) -> FrameSelection:
        """The frames whose masks a run reads: the planned ones; masks of frames the capture
        lacks are refused, those of frames the plan left out are skipped unread."""
        return FrameSelection(frozenset(self.names), frozenset(self.listed))

    def describe(self) -> str:
        """One line for people, e.g. ``training at 600x340 (1200x680 / 2, ...); 60 of 60 ...``."""
        (w, h), (ow, oh), b = self.size, self.output_size, self.budget
        side = "native" if b.max_side is None else f"longer side <= {b.max_side}"
        cap = "no cap" if b.max_keyframes is None else f"at most {b.max_keyframes}"
        return (
            f"training at {w}x{h} ({ow}x{oh} / {self.factor}, {side}); "
            f"{len(self.frames)} of {len(self.listed)} frames ({self.moved} moved "
            f">= {b.min_translation:g} m or {b.min_rotation_deg:g} deg, {cap}); "
            f"outputs at {ow}x{oh}"
        )

    def summary(self) -> dict[str, Any]:
        """The ``capture`` record of ``run.json``."""
        return {
            "output_size": list(self.output_size),
            "size": list(self.size),
            "factor": self.factor,
            "listed": len(self.listed),
            "moved": self.moved,
            "kept": len(self.frames),
            "budget": {
                "max_side": self.budget.max_side,
                "max_keyframes": self.budget.max_keyframes,
                "min_translation": self.budget.min_translation,
                "min_rotation_deg": self.budget.min_rotation_deg,
            },
            "frames": list(self.names),
            "listed_frames": list(self.listed),
        }


def downscale_factor(size: tuple[int, int], max_side: int | None) -> int:
    """The smallest integer factor bringing ``max(size)`` to at most ``max_side`` (None = 1)."""
    if max_side is None:
        return 1
    return max(1, math.ceil(max(size) / max_side))


def _scaled(size: tuple[int, int], factor: int) -> tuple[int, int]:
    return max(1, round(size[0] / factor)), max(1, round(size[1] / factor))


def _rotation_deg(a: NDArray[np.float64], b: NDArray[np.float64]) -> float:
    cos = (np.trace(a[:3, :3].T @ b[:3, :3]) - 1.0) / 2.0
    return math.degrees(math.acos(float(np.clip(cos, -1.0, 1.0))))


def _moved(last: NDArray[np.float64], pose: NDArray[np.float64], budget: FrameBudget) -> bool:
    if not (np.isfinite(pose).all() and np.isfinite(last).all()):
        return True
    shift = float(np.linalg.norm(pose[:3, 3] - last[:3, 3]))
    return shift >= budget.min_translation or _rotation_deg(last, pose) >= budget.min_rotation_deg


def keyframes(c2w: NDArray[np.float64], budget: FrameBudget) -> tuple[list[int], int]:
    """Indices of the keyframes of ``[F, 4, 4]`` poses, and how many moved before the cap."""
    if len(c2w) == 0:
        return [], 0
    kept = [0]
    for i in range(1, len(c2w)):
        if _moved(c2w[kept[-1]], c2w[i], budget):
            kept.append(i)
    moved = len(kept)
    if budget.max_keyframes is not None and moved > budget.max_keyframes:
        picks = np.round(np.linspace(0, moved - 1, budget.max_keyframes)).astype(np.int64)
        kept = [kept[int(p)] for p in picks]
    return kept, moved


def plan_capture(meta: CaptureMeta, budget: FrameBudget) -> CapturePlan:
    """The resolution and keyframes ``budget`` gives ``meta`` (module docstring: the rules)."""
    factor = downscale_factor(meta.size, budget.max_side)
    frames, moved = keyframes(meta.c2w, budget)
    return CapturePlan(
        budget=budget,
        output_size=meta.size,
        size=_scaled(meta.size, factor),
        factor=factor,
        listed=meta.names,
        moved=moved,
        frames=tuple(frames),
    )
