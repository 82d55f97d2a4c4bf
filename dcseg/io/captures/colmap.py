"""COLMAP sparse model layout, with depth maps.

::

    sparse/0/cameras.bin|txt    intrinsics (COLMAP camera models)
    sparse/0/images.bin|txt     per image: world-to-camera quaternion (qw qx qy qz) + translation
    sparse/0/points3D.bin|txt   optional: checks that the depth maps share the model's scale
    images/<name>               colour, ``<name>`` as in the images file (may hold folders)
    depth/<name stem>.png       uint16 millimetres (0 = none), or
    depth/<name stem>.npy       float32 metres (0 = none)

The model may also sit directly in ``sparse/``. When both exist, ``.bin`` files are read (as
COLMAP's own ``read_model`` does). Byte layouts follow COLMAP's reference reader
(``scripts/python/read_write_model.py``), all little-endian:

* ``cameras.bin``: ``uint64`` count, then per camera ``int32`` id, ``int32`` model id,
  ``uint64`` width, ``uint64`` height, one ``float64`` per model parameter;
* ``images.bin``: ``uint64`` count, then per image ``int32`` id, ``float64`` qw qx qy qz tx ty
  tz, ``int32`` camera id, the name as NUL-terminated UTF-8, ``uint64`` number of 2D points
  and per point ``float64`` x, ``float64`` y, ``int64`` 3D point id (skipped).

Conversions to dcseg's conventions (``docs/conventions.md``): COLMAP's camera axes are OpenCV's;
its pose is world-to-camera, ``x_cam = R(q) x_world + t``, so ``c2w = [R^T | -R^T t]``. COLMAP
puts the centre of the top-left pixel at (0.5, 0.5), dcseg at (0, 0): ``cx = cx_colmap - 0.5``
(same for ``cy``).

Camera models: ``SIMPLE_PINHOLE`` and ``PINHOLE``; ``SIMPLE_RADIAL``, ``RADIAL``, ``OPENCV``,
``FULL_OPENCV`` (OpenCV's radial-tangential model, its coefficients in COLMAP's order = OpenCV's)
and ``OPENCV_FISHEYE`` (OpenCV's fisheye model) with their distortion: the frames are
undistorted when they are read, and masks given for the distorted images with them
(:mod:`dcseg.lens`). ``FOV``, ``SIMPLE_RADIAL_FISHEYE``, ``RADIAL_FISHEYE`` and
``THIN_PRISM_FISHEYE`` are refused: undistort first with ``colmap image_undistorter``, which
writes ``PINHOLE`` cameras and undistorted images (as 3DGS's ``convert.py`` does).

Without a ``depth/`` folder the capture is RGB-only (``Capture.depth_source == "none"``, every
frame's depth all 0): ``points3D`` is then required and read (:mod:`.colmap_points`), the
Gaussians are initialised from it and trained with photometric losses only
(:mod:`dcseg.reconstruct.rgbonly`, which lists the steps that are off). The model's scale is then
arbitrary, so options stated in metres are in its units. With ``depth/``, depth must be metric
and in the model's units, so a model from images alone must first be scaled to metres (e.g.
``colmap model_aligner``); with ``points3D``, :mod:`.colmap_scale` checks it. Depth
at another resolution than its image is resampled onto it (nearest; same field of view).
Frames are named by the image name without its extension, sorted naturally.
"""

from __future__ import annotations

import math
import posixpath
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from dcseg.config import CaptureOptions
from dcseg.errors import InputError, Problem
from dcseg.io.captures.binary import BinaryReader, open_binary
from dcseg.io.captures.colmap_points import read_points3d
from dcseg.io.captures.colmap_scale import Observed, scale_problem
from dcseg.io.captures.common import (
    Camera,
    FrameSpec,
    Listing,
    add_if_present,
    numeric_sort_key,
    rel,
    warn_if_options_intrinsics,
)
from dcseg.io.folders import inside
from dcseg.types import Lens

__all__ = ["MODELS", "list_frames", "matches", "model_folder"]

MODELS: dict[int, tuple[str, int]] = {
    0: ("SIMPLE_PINHOLE", 3),
    1: ("PINHOLE", 4),
    2: ("SIMPLE_RADIAL", 4),
    3: ("RADIAL", 5),
    4: ("OPENCV", 8),
    5: ("OPENCV_FISHEYE", 8),
    6: ("FULL_OPENCV", 12),
    7: ("FOV", 5),
    8: ("SIMPLE_RADIAL_FISHEYE", 4),
    9: ("RADIAL_FISHEYE", 5),
    10: ("THIN_PRISM_FISHEYE", 12),
}
"""COLMAP camera model id -> (name, number of parameters), as in COLMAP's reference reader."""

_BY_NAME = {name: (model_id, count) for model_id, (name, count) in MODELS.items()}
_ONE_FOCAL = {"SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL"}
_TWO_FOCAL = {"PINHOLE", "OPENCV", "FULL_OPENCV", "OPENCV_FISHEYE"}
_QUATERNION_TOLERANCE = 1e-3
_IMAGE_HEADER = 64 + 1 + 8  # fixed part, the shortest name (its NUL), the 2D point count
_UNDISTORT = (
    "dcseg reads the pinhole models and SIMPLE_RADIAL, RADIAL, OPENCV, FULL_OPENCV and "
    "OPENCV_FISHEYE (undistorting the images); undistort the images first with "
    "`colmap image_undistorter` or, without COLMAP, `pip install pycolmap` and "
    "`pycolmap.undistort_images(OUT, MODEL_FOLDER, IMAGES_FOLDER)` (both write PINHOLE cameras "
    "and undistorted images; segment those)"
)
_NO_POINTS = (
    "missing: an RGB-only COLMAP capture (no depth/ folder) is initialised from the sparse "
    "points, so it needs points3D.bin or points3D.txt beside cameras and images"
)


@dataclass(frozen=True)
class _Camera:
    model: str
    width: int
    height: int
    params: tuple[float, ...]
    source: str


@dataclass(frozen=True)
class _Image:
    q: tuple[float, float, float, float]  # qw qx qy qz
    t: tuple[float, float, float]
    camera_id: int
    name: str
    source: str
    points: tuple[int, int] = (0, 0)  # its 2D points: (byte offset, count) or (line index, -1)


def model_folder(root: Path) -> Path | None:
    """``sparse/0`` or ``sparse`` if it holds ``cameras`` and ``images`` (.bin or .txt)."""
    for folder in (root / "sparse" / "0", root / "sparse"):
        if all(_model_file(folder, part) is not None for part in ("cameras", "images")):
            return folder
    return None


def _model_file(folder: Path, part: str) -> Path | None:
    for suffix in (".bin", ".txt"):
        if (folder / f"{part}{suffix}").is_file():
            return folder / f"{part}{suffix}"
    return None


def matches(root: Path) -> bool:
    """Whether ``root`` holds a COLMAP sparse model in ``sparse/0/`` or ``sparse/``."""
    return model_folder(root) is not None


# --- text files --------------------------------------------------------------------------------


def _text_lines(path: Path, shown: str) -> list[str]:
    try:
        return path.read_text(encoding="utf-8", errors="replace").splitlines()
    except OSError as exc:
        raise InputError.single(shown, f"cannot read file ({exc.strerror})") from None


def _is_data(line: str) -> bool:
    stripped = line.strip()
    return bool(stripped) and not stripped.startswith("#")


def _numbers(values: list[str], where: str, what: str) -> list[float]:
    try:
        out = [float(v) for v in values]
    except ValueError:
        raise InputError.single(where, f"{what} must be numbers, got {' '.join(values)}") from None
    if not all(math.isfinite(v) for v in out):
        raise InputError.single(where, f"{what} must be finite, got {' '.join(values)}")
    return out


def _integer(value: str, where: str, what: str) -> int:
    try:
        return int(value)
    except ValueError:
        raise InputError.single(where, f"{what} must be an integer, got {value!r}") from None


def _cameras_text(path: Path, shown: str) -> dict[int, _Camera]:
    """``CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]`` per line."""
    cameras: dict[int, _Camera] = {}
    for number, line in enumerate(_text_lines(path, shown), start=1):
        if not _is_data(line):
            continue
        where, values = f"{shown}:line {number}", line.split()
        if len(values) < 4:
            raise InputError.single(
                where, f"expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS[], got {len(values)} values"
            )
        camera_id = _integer(values[0], where, "CAMERA_ID")
        model = values[1]
        if model not in _BY_NAME:
            raise InputError.single(where, _unknown_model(model))
        count = _BY_NAME[model][1]
        if len(values) - 4 != count:
            raise InputError.single(where, f"{model} has {count} parameters, got {len(values) - 4}")
        width, height = (
            _integer(v, where, k) for v, k in zip(values[2:4], ("WIDTH", "HEIGHT"), strict=True)
        )
        params = tuple(_numbers(values[4:], where, "PARAMS"))
        cameras[camera_id] = _Camera(model, width, height, params, f"{where} (camera {camera_id})")
    return cameras


def _images_text(path: Path, shown: str) -> list[_Image]:
    """Two lines per image: ``IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME``, then its 2D points
    (which may be an empty line; not read)."""
    lines = _text_lines(path, shown)
    images: list[_Image] = []
    index = 0
    while index < len(lines):
        line, number = lines[index], index + 1
        index += 1
        if not _is_data(line):
            continue
        points = (index, -1)  # the 2D points line
        index += 1
        where, values = f"{shown}:line {number}", line.split()
        if len(values) < 10:
            raise InputError.single(
                where,
                f"expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME, got {len(values)} values",
            )
        pose = _numbers(values[1:8], where, "QW QX QY QZ TX TY TZ")
        camera_id = _integer(values[8], where, "CAMERA_ID")
        name = " ".join(values[9:])
        images.append(_image(pose, camera_id, name, f"{where} (image {values[0]})", points))
    return images


def _image(
    pose: list[float], camera_id: int, name: str, source: str, points: tuple[int, int]
) -> _Image:
    qw, qx, qy, qz, tx, ty, tz = pose
    return _Image((qw, qx, qy, qz), (tx, ty, tz), camera_id, name, source, points)


def _unknown_model(model: str) -> str:
    known = ", ".join(name for name, _ in MODELS.values())
    return f"unknown camera model {model!r} (COLMAP's models are {known})"


# --- binary files ------------------------------------------------------------------------------


def _cameras_binary(path: Path, shown: str) -> dict[int, _Camera]:
    handle, size = open_binary(path, shown)
    with handle:
        data = BinaryReader(handle, size, shown)
        cameras: dict[int, _Camera] = {}
        for k in range(data.count("camera", 24)):
            field = f"camera {k + 1}"
            camera_id, model_id, width, height = data.take("iiQQ", f"{field}: id/model/size")
            if model_id not in MODELS:
                raise InputError.single(
                    shown, f"{field} (id {camera_id}): unknown camera model id {model_id}"
                )
            model, params = MODELS[model_id]
            values = data.take("d" * params, f"{field} (id {camera_id}): {model} parameters")
            source = f"{shown}:camera {camera_id}"
            cameras[camera_id] = _Camera(model, width, height, tuple(values), source)
    return cameras


def _images_binary(path: Path, shown: str) -> list[_Image]:
    handle, size = open_binary(path, shown)
    images: list[_Image] = []
    with handle:
        data = BinaryReader(handle, size, shown)
        for k in range(data.count("image", _IMAGE_HEADER)):
            field = f"image {k + 1}"
            values = data.take("i7di", f"{field}: id/qvec/tvec/camera id")
            image_id, pose, camera_id = values[0], values[1:8], values[8]
            name = data.name(f"{field} (id {image_id}): name")
            (points,) = data.take("Q", f"{field} (id {image_id}): the number of 2D points")
            at = handle.tell()
            data.skip(24 * points, f"{field} (id {image_id}): {points} 2D points")
            source = f"{shown}:image {image_id}"
            images.append(_image(list(pose), camera_id, name, source, (at, points)))
    return images


# --- frames ------------------------------------------------------------------------------------


def _read_model(root: Path, folder: Path) -> tuple[dict[int, _Camera], list[_Image]]:
    cameras_path, images_path = _model_file(folder, "cameras"), _model_file(folder, "images")
    assert cameras_path is not None and images_path is not None
    cam_shown, img_shown = rel(cameras_path, root), rel(images_path, root)
    binary = cameras_path.suffix == ".bin"
    cameras = (_cameras_binary if binary else _cameras_text)(cameras_path, cam_shown)
    binary = images_path.suffix == ".bin"
    images = (_images_binary if binary else _images_text)(images_path, img_shown)
    return cameras, images


def _pinhole(camera: _Camera) -> Camera | str:
    """The intrinsics (and lens) of a camera in dcseg's pixel convention, or why there are
    none."""
    params = camera.params
    if camera.model in _ONE_FOCAL:
        focal, distortion = (params[0], params[0], params[1], params[2]), params[3:]
    elif camera.model in _TWO_FOCAL:
        focal, distortion = (params[0], params[1], params[2], params[3]), params[4:]
    else:
        return f"camera model {camera.model} is not supported: {_UNDISTORT}"
    fx, fy, cx, cy = focal
    size = (camera.width, camera.height)
    lens = _lens(camera.model, distortion, camera.source)
    return Camera(fx, fy, cx - 0.5, cy - 0.5, size, camera.source, lens)


def _lens(model: str, distortion: tuple[float, ...], source: str) -> Lens | None:
    """A COLMAP model's distortion parameters in OpenCV's order (None without distortion)."""
    if not any(distortion):
        return None
    if model == "OPENCV_FISHEYE":
        return Lens("fisheye", distortion, f"{source} ({model})")
    padded = {"SIMPLE_RADIAL": (*distortion, 0.0, 0.0, 0.0), "RADIAL": (*distortion, 0.0, 0.0)}
    return Lens("opencv", padded.get(model, distortion), f"{source} ({model})")


def _c2w(image: _Image) -> NDArray[np.float64] | str:
    qw, qx, qy, qz = image.q
    norm = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    if abs(norm - 1.0) > _QUATERNION_TOLERANCE:
        return f"quaternion (QW, QX, QY, QZ) has norm {norm:.6g}, expected 1"
    rotation = Rotation.from_quat([qx, qy, qz, qw]).as_matrix()  # world-to-camera
    c2w = np.eye(4)
    c2w[:3, :3] = rotation.T
    c2w[:3, 3] = -rotation.T @ np.asarray(image.t, dtype=np.float64)
    return c2w


def _depth_file(root: Path, stem: str) -> Path:
    png = root / "depth" / f"{stem}.png"
    npy = root / "depth" / f"{stem}.npy"
    return npy if npy.is_file() and not png.is_file() else png


def list_frames(root: Path, options: CaptureOptions) -> Listing:
    """List the registered images of a COLMAP model with their depth maps.

    A camera that is not a pinhole one is reported once (naming the camera); its images are
    left out without repeating it.

    Raises:
        InputError: a model file is malformed or truncated (naming the file, the line or
            image/camera and the field).
    """
    folder = model_folder(root)
    assert folder is not None
    warn_if_options_intrinsics(options, "COLMAP")
    cameras, images = _read_model(root, folder)
    listing = Listing(resample_depth=True)
    rgb_only = not (root / "depth").is_dir()
    if rgb_only:
        _add_sparse(root, folder, listing)
    intrinsics = {camera_id: _pinhole(camera) for camera_id, camera in cameras.items()}
    for camera_id, found in sorted(intrinsics.items()):
        if isinstance(found, str):
            listing.problems.append(Problem(cameras[camera_id].source, found))
    for image in sorted(images, key=lambda im: numeric_sort_key(im.name)):
        _add_image(root, image, intrinsics, listing, rgb_only)
    if listing.specs and not listing.problems and not rgb_only:
        _check_scale(root, folder, images, listing, options.pose_scale)
    return listing


def _add_sparse(root: Path, folder: Path, listing: Listing) -> None:
    """Mark the listing RGB-only and attach the model's sparse points (or say they are missing)."""
    listing.depth_source = "none"
    points = _model_file(folder, "points3D")
    if points is None:
        listing.problems.append(Problem(rel(folder / "points3D.bin", root), _NO_POINTS))
        return
    listing.sparse = read_points3d(points, rel(points, root))
    if not len(listing.sparse):
        listing.problems.append(Problem(listing.sparse.source, "holds no points: " + _NO_POINTS))


def _check_scale(
    root: Path, folder: Path, images: list[_Image], listing: Listing, pose_scale: float | None
) -> None:
    """Refuse depth maps whose scale is not the model's (:mod:`.colmap_scale`)."""
    by_name = {posixpath.splitext(image.name)[0]: image for image in images}
    observed = [Observed(spec, by_name[spec.name].points) for spec in listing.specs]
    images_path = _model_file(folder, "images")
    assert images_path is not None
    points = _model_file(folder, "points3D")
    problem = scale_problem(root, images_path, points, observed, pose_scale)
    if problem is not None:
        listing.problems.append(problem)


def _add_image(
    root: Path, image: _Image, intrinsics: dict[int, Camera | str], listing: Listing, rgb_only: bool
) -> None:
    name = posixpath.splitext(image.name)[0]
    camera = intrinsics.get(image.camera_id)
    reasons: list[str] = [] if name else ["NAME is empty"]
    if camera is None:
        reasons.append(f"CAMERA_ID {image.camera_id}: no such camera in the cameras file")
    pose = _c2w(image)
    if isinstance(pose, str):
        reasons.append(pose)
    rgb = inside(root / "images", image.name)
    if rgb is None:
        reasons.append(f"NAME {image.name!r} must stay inside images/")
        rgb = root / "images"
    listing.problems.extend(Problem(image.source, reason) for reason in reasons)
    if reasons or not isinstance(camera, Camera) or isinstance(pose, str):
        listing.unlisted.append(name)
        return
    depth = None if rgb_only else _depth_file(root, name)
    spec = FrameSpec(name, rgb, depth, pose, camera, image.source)
    add_if_present(listing, spec, root)
