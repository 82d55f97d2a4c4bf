"""Whether a COLMAP model and its depth maps share one scale (the model must be in metres).

A model made by structure from motion alone has an arbitrary scale; depth maps are metric. If
the two disagree, the depth loss and the poses pull the reconstruction apart, so a mismatch is
refused rather than trained on. The check compares, for a few frames spread over the capture,
the depth map at each observed sparse point (an image's 2D points with a 3D point id) with that
point's depth in the camera (its z after ``inverse(c2w)``): the median ratio must lie within
:data:`SCALE_RANGE`. With fewer than :data:`MIN_POINTS` usable points the check is skipped.

2D points are in COLMAP's pixel convention (the top-left pixel covers [0, 1) x [0, 1)): the
depth pixel of ``(x, y)`` is ``(floor(x * dw / W), floor(y * dh / H))``.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from dcseg.errors import InputError, Problem
from dcseg.io.captures.binary import BinaryReader, open_binary
from dcseg.io.captures.common import FrameSpec, read_depth, rel

__all__ = ["MIN_POINTS", "SAMPLES", "SCALE_RANGE", "Observed", "scale_problem"]

logger = logging.getLogger(__name__)

SCALE_RANGE = (0.8, 1.25)
"""Accepted median of depth map / model depth at the sparse points."""
MIN_POINTS = 20
"""Fewest usable sparse points for the check to run."""
SAMPLES = 3
"""Frames the check reads depth for (spread over the capture)."""

_OBSERVATION = np.dtype([("x", "<f8"), ("y", "<f8"), ("id", "<i8")])


@dataclass(frozen=True)
class Observed:
    """A listed frame and where its image's 2D points are in the images file.

    Attributes:
        spec: the frame.
        points: ``(byte offset, count)`` in ``images.bin`` or ``(line index, -1)`` in
            ``images.txt``.
    """

    spec: FrameSpec
    points: tuple[int, int]


def scale_problem(
    root: Path,
    images: Path,
    points3d: Path | None,
    frames: Sequence[Observed],
    pose_scale: float | None = None,
) -> Problem | None:
    """The problem of a model whose scale (times ``pose_scale``, the user's metres per model
    unit, when given) disagrees with its depth maps, or None.

    Raises:
        InputError: a model file or a sampled depth map cannot be read.
    """
    if points3d is None or not frames:
        return None
    step = max(1, len(frames) // SAMPLES)
    chosen = list(frames[::step][:SAMPLES])
    text = images.suffix == ".txt"
    lines = images.read_text(encoding="utf-8", errors="replace").splitlines() if text else []
    observations = [_observations(images, frame.points, lines) for frame in chosen]
    wanted = {int(i) for obs in observations for i in obs["id"] if i >= 0}
    xyz = _points(points3d, rel(points3d, root), wanted)
    ratios = np.concatenate(
        [
            _ratios(frame.spec, obs, xyz, root)
            for frame, obs in zip(chosen, observations, strict=True)
        ]
    )
    if ratios.size < MIN_POINTS:
        logger.debug("COLMAP scale check skipped: %d usable sparse points", ratios.size)
        return None
    median = float(np.median(ratios)) / (pose_scale or 1.0)
    if SCALE_RANGE[0] <= median <= SCALE_RANGE[1]:
        return None
    model = "model depth" if pose_scale is None else f"(model depth x pose_scale {pose_scale:g})"
    return Problem(
        rel(points3d, root),
        f"the model and the depth maps disagree in scale: depth map / {model} at "
        f"{ratios.size} sparse points of {len(chosen)} frames has median {median:.3g} (expected "
        "1): scale the model to metres (e.g. colmap model_aligner or capture.pose_scale) or "
        "give metric depth",
    )


def _observations(images: Path, points: tuple[int, int], lines: list[str]) -> NDArray[np.void]:
    at, count = points
    if count < 0:  # text: the line of "X Y POINT3D_ID" triples
        line = lines[at] if at < len(lines) else ""
        try:
            values = np.array([float(v) for v in line.split()], dtype=np.float64)
        except ValueError:
            values = np.zeros(0)
        values = values[: values.size // 3 * 3].reshape(-1, 3)
        values = values[np.isfinite(values).all(axis=1)]
        out = np.zeros(len(values), dtype=_OBSERVATION)
        out["x"], out["y"], out["id"] = values[:, 0], values[:, 1], values[:, 2].astype(np.int64)
        return out
    with images.open("rb") as handle:
        handle.seek(at)
        return np.frombuffer(handle.read(24 * count), dtype=_OBSERVATION)


def _xyz(values: list[str], where: str) -> NDArray[np.float64]:
    """``X Y Z`` of a ``points3D.txt`` line; an :class:`InputError` naming ``where`` unless
    all three are finite numbers."""
    shown = " ".join(values)
    try:
        xyz = np.array([float(v) for v in values], dtype=np.float64)
    except ValueError:
        raise InputError.single(where, f"expected X Y Z numbers, got {shown!r}") from None
    if not np.isfinite(xyz).all():
        raise InputError.single(where, f"X Y Z must be finite, got {shown!r}")
    return xyz


def _points(path: Path, shown: str, wanted: set[int]) -> dict[int, NDArray[np.float64]]:
    """The coordinates of the ``wanted`` 3D points (``points3D.bin`` or ``.txt``)."""
    found: dict[int, NDArray[np.float64]] = {}
    if path.suffix == ".txt":
        lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
        for number, line in enumerate(lines, 1):
            values = line.split()
            if len(values) >= 4 and not values[0].startswith("#") and values[0].isdigit():
                if int(values[0]) in wanted:
                    found[int(values[0])] = _xyz(values[1:4], f"{shown}:line {number}")
        return found
    handle, size = open_binary(path, shown)
    with handle:
        data = BinaryReader(handle, size, shown)
        for k in range(data.count("point", 43 + 8)):
            point_id, x, y, z, *_ = data.take("QdddBBBd", f"point {k + 1}")
            (track,) = data.take("Q", f"point {k + 1} (id {point_id}): track length")
            data.skip(8 * track, f"point {k + 1} (id {point_id}): {track} track elements")
            if point_id in wanted:
                found[point_id] = np.array([x, y, z])
                if len(found) == len(wanted):
                    break
    return found


def _ratios(
    spec: FrameSpec, obs: NDArray[np.void], xyz: dict[int, NDArray[np.float64]], root: Path
) -> NDArray[np.float64]:
    known = [i for i, point_id in enumerate(obs["id"]) if int(point_id) in xyz]
    if not known or spec.camera.size is None:
        return np.zeros(0)
    try:
        depth = read_depth(spec, root)
    except InputError:
        return np.zeros(0)  # the loader reports it
    world = np.stack([xyz[int(obs["id"][i])] for i in known])
    w2c = np.linalg.inv(spec.c2w)
    z = world @ w2c[2, :3] + w2c[2, 3]
    width, height = spec.camera.size
    cols = np.floor(obs["x"][known] * depth.shape[1] / width).astype(np.int64)
    rows = np.floor(obs["y"][known] * depth.shape[0] / height).astype(np.int64)
    inside = (cols >= 0) & (cols < depth.shape[1]) & (rows >= 0) & (rows < depth.shape[0])
    measured = depth[rows.clip(0, depth.shape[0] - 1), cols.clip(0, depth.shape[1] - 1)]
    usable = inside & (measured > 0) & (z > 1e-9)
    ratios: NDArray[np.float64] = measured[usable].astype(np.float64) / z[usable]
    return ratios[np.isfinite(ratios)]
