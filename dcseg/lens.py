"""Lens distortion: frames resampled onto pinhole cameras, and the masks made for them.

dcseg renders pinhole cameras. A layout whose camera states lens distortion (a
:class:`~dcseg.types.Lens`: COLMAP's ``SIMPLE_RADIAL``, ``RADIAL``, ``OPENCV``, ``FULL_OPENCV``
and ``OPENCV_FISHEYE`` models, nerfstudio's ``k1..k4 p1 p2``, TUM's ``d0..d4`` calibration) has
its frames resampled when they are read (:func:`undistort`): onto the pinhole camera of the same
size whose every pixel sees the scene and whose view is the widest such (OpenCV's
``getOptimalNewCameraMatrix`` with ``alpha`` 0; ``estimateNewCameraMatrixForUndistortRectify``
with ``balance`` 0 for fisheye lenses). Colour is resampled bilinearly; depth and confidence
by nearest neighbour, so that no depth is mixed across an edge.

Masks and class maps made on the distorted images are resampled the same way (nearest
neighbour) when a job reads them (:func:`undistort_agnostic`, :func:`undistort_semantic`).
``run.json`` records every frame's undistortion (:func:`records`, read back by
:func:`from_records`), so that re-classifying a run with new masks resamples them too. Per-view
outputs (``labels/``, ``masks/``) are brought back onto the capture's own distorted images
(:func:`redistort_labels`), so that they overlay the images the user has.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from functools import lru_cache, partial
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from dcseg.types import AgnosticMasks, Frame, Intrinsics, Lens, SemanticMap, Undistortion

__all__ = [
    "from_records",
    "lens_problem",
    "nearest_pixels",
    "of_frames",
    "of_record",
    "pinhole_for",
    "records",
    "redistort_labels",
    "remap_linear",
    "remap_nearest",
    "undistort",
    "undistort_agnostic",
    "undistort_semantic",
    "undistortion",
]

_COUNTS = {"opencv": (4, 5, 8), "fisheye": (4,)}
"""Coefficient counts OpenCV accepts per model."""


def lens_problem(lens: Lens) -> str | None:
    """Why OpenCV cannot use ``lens``, or None."""
    counts = _COUNTS.get(lens.model)
    if counts is None:
        return f"unknown lens model {lens.model!r} (expected opencv or fisheye)"
    if len(lens.coefficients) not in counts:
        return (
            f"{lens.model} lens needs {' or '.join(map(str, counts))} coefficients, "
            f"got {len(lens.coefficients)}"
        )
    if not all(np.isfinite(lens.coefficients)):
        return f"lens coefficients must be finite, got {list(lens.coefficients)}"
    return None


def pinhole_for(lens: Lens, source: Intrinsics) -> Intrinsics:
    """The pinhole camera of ``source``'s size that the undistorted image is resampled onto:
    every pixel inside the distorted image, the widest view that allows."""
    k, size = source.matrix(), (source.width, source.height)
    coefficients = np.asarray(lens.coefficients, dtype=np.float64)
    if lens.model == "fisheye":
        new = cv2.fisheye.estimateNewCameraMatrixForUndistortRectify(
            k, coefficients.reshape(4, 1), size, np.eye(3), balance=0.0
        )
    else:
        new, _ = cv2.getOptimalNewCameraMatrix(k, coefficients, size, 0.0, size)
    return Intrinsics.from_matrix(np.asarray(new, dtype=np.float64), *size)


@lru_cache(maxsize=64)
def undistortion(lens: Lens, source: Intrinsics) -> Undistortion:
    """The undistortion of images of ``source`` taken through ``lens``."""
    return Undistortion(lens, source, pinhole_for(lens, source))


@lru_cache(maxsize=4)
def _maps(u: Undistortion, width: int, height: int) -> tuple[NDArray[np.float32], ...]:
    """Where each pixel of the undistorted image lies in the distorted one, at ``width`` x
    ``height``: ``(x, y)``, read-only (8 bytes a pixel; a capture has one or a few cameras,
    and masks are read at the working size: a few entries suffice)."""
    source = u.source.scaled(width, height).matrix()
    pinhole = u.pinhole.scaled(width, height).matrix()
    coefficients = np.asarray(u.lens.coefficients, dtype=np.float64)
    size = (width, height)
    if u.lens.model == "fisheye":
        x, y = cv2.fisheye.initUndistortRectifyMap(
            source, coefficients.reshape(4, 1), np.eye(3), pinhole, size, cv2.CV_32FC1
        )
    else:
        x, y = cv2.initUndistortRectifyMap(source, coefficients, None, pinhole, size, cv2.CV_32FC1)
    out = (np.asarray(x, np.float32), np.asarray(y, np.float32))
    for array in out:
        array.flags.writeable = False
    return out


def nearest_pixels(u: Undistortion, width: int, height: int) -> tuple[NDArray[np.int32], ...]:
    """``(rows, columns)`` of the distorted pixel nearest each undistorted one."""
    x, y = _maps(u, width, height)
    rows = np.clip(np.floor(y + 0.5), 0, height - 1).astype(np.int32)
    return rows, np.clip(np.floor(x + 0.5), 0, width - 1).astype(np.int32)


def remap_linear(image: NDArray[Any], u: Undistortion) -> NDArray[Any]:
    """``image`` (distorted, any size of ``u``'s aspect) undistorted, bilinearly."""
    x, y = _maps(u, int(image.shape[1]), int(image.shape[0]))
    return np.asarray(
        cv2.remap(image, x, y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE),
        dtype=image.dtype,
    )


def remap_nearest(image: NDArray[Any], u: Undistortion) -> NDArray[Any]:
    """``image`` undistorted by nearest neighbour (depth, confidence, masks, class maps)."""
    rows, cols = nearest_pixels(u, int(image.shape[1]), int(image.shape[0]))
    return np.ascontiguousarray(image[rows, cols])


@lru_cache(maxsize=4)
def _inverse(u: Undistortion, width: int, height: int) -> tuple[NDArray[Any], ...]:
    """For each pixel of the distorted image at ``width`` x ``height``: ``(rows, columns)`` of
    the nearest undistorted pixel, and ``[H, W]`` bool whether it lies inside the undistorted
    image (read-only)."""
    source = u.source.scaled(width, height).matrix()
    pinhole = u.pinhole.scaled(width, height).matrix()
    coefficients = np.asarray(u.lens.coefficients, dtype=np.float64)
    v, x = np.mgrid[0:height, 0:width].astype(np.float64)
    points = np.stack([x.ravel(), v.ravel()], axis=1).reshape(-1, 1, 2)
    if u.lens.model == "fisheye":
        mapped = cv2.fisheye.undistortPoints(points, source, coefficients.reshape(4, 1), P=pinhole)
    else:
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-6)
        mapped = cv2.undistortPoints(
            points, source, coefficients, R=None, P=pinhole, criteria=criteria
        )
    mapped = np.asarray(mapped, dtype=np.float64).reshape(height, width, 2)
    cols, rows = np.floor(mapped[..., 0] + 0.5), np.floor(mapped[..., 1] + 0.5)
    inside = (cols >= 0) & (cols < width) & (rows >= 0) & (rows < height)
    out = (
        np.clip(rows, 0, height - 1).astype(np.int32),
        np.clip(cols, 0, width - 1).astype(np.int32),
        inside,
    )
    for array in out:
        array.flags.writeable = False
    return out


def redistort_labels(labels: NDArray[Any], u: Undistortion) -> NDArray[Any]:
    """A per-pixel id map of the undistorted frame (any size of its aspect) brought back onto
    the distorted image's pixels by nearest neighbour, -1 where the undistorted view does not
    reach (so that label maps overlay the capture's own images)."""
    height, width = (int(v) for v in labels.shape[:2])
    rows, cols, inside = _inverse(u, width, height)
    return np.where(inside, labels[rows, cols], -1).astype(labels.dtype)


def undistort(
    rgb: NDArray[np.uint8], depth: NDArray[np.float32], u: Undistortion
) -> tuple[NDArray[np.uint8], NDArray[np.float32]]:
    """A frame's colour (bilinear) and depth (nearest, on the colour grid) undistorted."""
    return remap_linear(rgb, u), remap_nearest(depth, u)


def undistort_agnostic(
    masks: Mapping[str, AgnosticMasks], frames: Mapping[str, Undistortion]
) -> dict[str, AgnosticMasks]:
    """Masks made on distorted images, resampled like their frames (masks left with no pixel
    are dropped); frames without an undistortion keep theirs."""
    from dcseg.io.masks import map_masks

    out: dict[str, AgnosticMasks] = {}
    for name, m in masks.items():
        u = frames.get(name)
        size = (m.width, m.height)
        out[name] = m if u is None else map_masks(m, partial(remap_nearest, u=u), size)
    return out


def undistort_semantic(
    maps: Mapping[str, SemanticMap], frames: Mapping[str, Undistortion]
) -> dict[str, SemanticMap]:
    """Class maps made on distorted images, resampled like their frames."""
    out: dict[str, SemanticMap] = {}
    for name, m in maps.items():
        u = frames.get(name)
        out[name] = m if u is None else SemanticMap(name, remap_nearest(m.classes, u), m.source)
    return out


def of_frames(frames: Iterable[Frame]) -> dict[str, Undistortion]:
    """Each undistorted frame's undistortion, by frame name."""
    return {f.name: f.undistortion for f in frames if f.undistortion is not None}


def records(frames: Mapping[str, Undistortion]) -> list[dict[str, Any]]:
    """The undistortions as ``run.json`` keeps them: one entry per distinct undistortion
    with its frames (``[]`` when no frame was undistorted)."""
    grouped: dict[Undistortion, list[str]] = {}
    for name, u in frames.items():
        grouped.setdefault(u, []).append(name)
    return [{**_record(u), "frames": names} for u, names in grouped.items()]


def from_records(entries: Iterable[Mapping[str, Any]]) -> dict[str, Undistortion]:
    """:func:`records` read back: the undistortion of every frame named there."""
    out: dict[str, Undistortion] = {}
    for entry in entries:
        lens = Lens(entry["model"], tuple(float(v) for v in entry["coefficients"]), entry["lens"])
        width, height = (int(v) for v in entry["size"])
        source, pinhole = (_intrinsics(entry[key], width, height) for key in ("source", "pinhole"))
        u = Undistortion(lens, source, pinhole)
        out.update((str(name), u) for name in entry["frames"])
    return out


def of_record(record: Mapping[str, Any]) -> dict[str, Undistortion]:
    """The undistorted frames of a run's ``run.json`` record (``capture.undistortion``)."""
    return from_records(record.get("capture", {}).get("undistortion", []))


def _intrinsics(values: list[float], width: int, height: int) -> Intrinsics:
    fx, fy, cx, cy = (float(v) for v in values)
    return Intrinsics(fx, fy, cx, cy, width, height)


def _record(u: Undistortion) -> dict[str, Any]:
    def k(c: Intrinsics) -> list[float]:
        return [c.fx, c.fy, c.cx, c.cy]

    return {
        "model": u.lens.model,
        "coefficients": list(u.lens.coefficients),
        "lens": u.lens.source,
        "size": [u.source.width, u.source.height],
        "source": k(u.source),
        "pinhole": k(u.pinhole),
    }
