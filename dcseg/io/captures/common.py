"""What every capture layout shares: frame specs, file parsing, and the post-processing.

A layout module only *lists* frames (:class:`Listing` of :class:`FrameSpec`, plus the problems
it found on the way). :func:`load_capture` then applies ``stride``/``max_frames``, reads images,
converts depth to metres, resamples, truncates and validates, for every layout in the same way.

Structural problems (missing files, malformed poses or JSON) are reported for every frame of the
capture; image problems (decoding, sizes) only for the frames selected by ``stride`` and
``max_frames``, since only those are read.
"""

from __future__ import annotations

import logging
import re
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TypeVar

import numpy as np
from numpy.typing import NDArray

from dcseg.config import CaptureOptions
from dcseg.errors import InputError, Problem
from dcseg.io import images
from dcseg.io.captures.depth_files import read_npy, register_depth
from dcseg.io.exr import read_exr_depth
from dcseg.io.images import display_path, read_image, resize_area, resize_nearest
from dcseg.io.lzfse_buffers import read_lzfse_array
from dcseg.lens import lens_problem, undistort, undistortion
from dcseg.types import (
    Capture,
    DepthSource,
    Frame,
    Intrinsics,
    Lens,
    SparsePoints,
    Undistortion,
    capture_problems,
)

logger = logging.getLogger(__name__)

_T = TypeVar("_T")
_R = TypeVar("_R")

OPTIONS_SOURCE = "CaptureOptions.intrinsics"
"""The ``source`` of a :class:`Camera` given through the options."""
DISTORTION_SOURCE = "CaptureOptions.distortion"
"""The ``source`` of a :class:`~dcseg.types.Lens` given through the options."""

RAW_DEPTH_SUFFIX = ".depth"
"""Depth files stored as LZFSE-compressed float32 metres of :attr:`FrameSpec.raw_size`."""
RAW_CONFIDENCE_SUFFIX = ".conf"
"""Confidence files stored as LZFSE-compressed uint8 levels of :attr:`FrameSpec.raw_size`."""


@dataclass(frozen=True)
class Camera:
    """Pinhole parameters as a layout states them.

    Attributes:
        fx, fy, cx, cy: in pixels of the colour image.
        size: the ``(width, height)`` they were stated for, or None to take the image's size.
        source: where they came from (a file, a JSON path or :data:`OPTIONS_SOURCE`).
        lens: the lens distortion stated with them; the frames are undistorted when they are
            read (:mod:`dcseg.lens`). None = a pinhole camera.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    size: tuple[int, int] | None
    source: str
    lens: Lens | None = None


@dataclass(frozen=True)
class FrameSpec:
    """Where one frame's parts are, before anything is decoded.

    Attributes:
        name: the frame name (masks are matched to it).
        rgb, depth: absolute paths of the colour and depth files; ``depth`` None = the frame
            has no depth (an RGB-only capture: its depth is all 0).
        c2w: ``[4, 4]`` camera-to-world pose in OpenCV axes (not yet validated).
        camera: the colour intrinsics.
        pose_source: where the pose came from, for messages.
        depth_scale: stored integer depth / ``depth_scale`` = metres (float files are metres).
        depth_invalid: stored integer values meaning "no depth" besides 0.
        depth_k: ``[3, 3]`` camera matrix of the depth image when it is registered to the colour
            image at another resolution (ScanNet); used to resample depth onto the colour grid.
        raw_size: ``(width, height)`` of depth and confidence stored as LZFSE-compressed raw
            buffers (Record3D ``.depth`` float32 metres, ``.conf`` uint8), from the metadata.
        confidence: the per-pixel ARKit confidence of the depth image (levels 0, 1, 2, at the
            depth resolution), for layouts that store one; read only when
            ``CaptureOptions.min_confidence`` > 0.
        rgb_frame: for colour stored as a video (Stray Scanner's ``rgb.mp4``), the 0-based
            index of this frame in the video ``rgb`` (:mod:`dcseg.io.video`); None = ``rgb``
            is an image file.
    """

    name: str
    rgb: Path
    depth: Path | None
    c2w: NDArray[np.float64]
    camera: Camera
    pose_source: str
    depth_scale: float = 1000.0
    depth_invalid: tuple[int, ...] = ()
    depth_k: NDArray[np.float64] | None = None
    raw_size: tuple[int, int] | None = None
    confidence: Path | None = None
    rgb_frame: int | None = None


@dataclass
class Listing:
    """A layout's frames in capture order, and the problems found while listing them.

    Attributes:
        specs: the frames that could be listed.
        problems: everything wrong found so far (reported together with loading problems).
        resample_depth: whether depth may come at another resolution than colour.
        unlisted: names of frames the layout names but could not list (a part is missing or
            its pose is malformed; the problem is in ``problems``).
        depth_source: ``"sensor"``, or ``"none"`` for an RGB-only capture (specs' depth None).
        sparse: the layout's sparse points, when it has them (COLMAP ``points3D``).
    """

    specs: list[FrameSpec] = field(default_factory=list)
    problems: list[Problem] = field(default_factory=list)
    resample_depth: bool = False
    unlisted: list[str] = field(default_factory=list)
    depth_source: DepthSource = "sensor"
    sparse: SparsePoints | None = None

    def unlist(self, name: str, problems: Iterable[Problem]) -> None:
        """Frame ``name`` cannot be listed, for ``problems``: both reported together."""
        self.problems.extend(problems)
        self.unlisted.append(name)


def scale_poses(listing: Listing, pose_scale: float | None) -> Listing:
    """``listing`` with its camera positions and sparse points multiplied by ``pose_scale``
    (``CaptureOptions.pose_scale``, metres per unit of the poses); itself when None."""
    if pose_scale is None:
        return listing
    specs = []
    for spec in listing.specs:
        c2w = np.array(spec.c2w, dtype=np.float64)
        c2w[:3, 3] *= pose_scale
        specs.append(replace(spec, c2w=c2w))
    sparse = listing.sparse
    if sparse is not None:
        sparse = replace(sparse, xyz=sparse.xyz * pose_scale)
    return replace(listing, specs=specs, sparse=sparse)


def rel(path: Path, root: Path) -> str:
    """``path`` relative to the capture root, ``/``-separated, for messages."""
    return display_path(path, root)


def missing(path: Path, root: Path, part: str, rgb: Path) -> Problem:
    """The problem of a frame part that is absent, e.g. ``depth/3.png: missing (...)``."""
    return Problem(rel(path, root), f"missing (colour {rel(rgb, root)} has no {part})")


def add_if_present(listing: Listing, spec: FrameSpec, root: Path) -> None:
    """Append ``spec`` to the listing, or a ``missing`` problem if its colour or depth is absent."""
    if not spec.rgb.is_file():
        listing.problems.append(missing(spec.rgb, root, "colour", spec.rgb))
    elif spec.depth is not None and not spec.depth.is_file():
        listing.problems.append(missing(spec.depth, root, "depth", spec.rgb))
    else:
        listing.specs.append(spec)
        return
    listing.unlisted.append(spec.name)


def frame_number(stem: str) -> int | None:
    """The last run of digits in a stem (``frame000012`` -> 12), or None."""
    digits = re.findall(r"\d+", stem)
    return int(digits[-1]) if digits else None


def numeric_sort_key(stem: str) -> tuple[int, str]:
    """Sort key putting ``2`` before ``10`` (stems without digits go last, by name)."""
    number = frame_number(stem)
    return (number if number is not None else 2**62, stem)


def read_matrix_txt(path: Path, root: Path) -> NDArray[np.float64]:
    """A whitespace-separated 4x4 matrix (ScanNet / 7-Scenes poses and intrinsics).

    Raises:
        InputError: the file is missing or does not hold 16 numbers in 4 rows.
    """
    shown = rel(path, root)
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except FileNotFoundError:
        raise InputError.single(shown, "missing") from None
    except OSError as exc:
        raise InputError.single(shown, f"cannot read file ({exc.strerror})") from None
    try:
        rows = [[float(v) for v in line.split()] for line in text.splitlines() if line.strip()]
        matrix = np.array(rows, dtype=np.float64)
    except ValueError:
        raise InputError.single(shown, "expected a 4x4 matrix of numbers") from None
    if matrix.shape != (4, 4):
        raise InputError.single(shown, f"expected a 4x4 matrix, got {_shape_words(rows)}")
    return matrix


def _shape_words(rows: list[list[float]]) -> str:
    widths = sorted({len(r) for r in rows})
    return f"{len(rows)} rows of {'/'.join(str(w) for w in widths) or 0} numbers"


def options_camera(options: CaptureOptions) -> Camera | None:
    """The intrinsics given in ``options``, stated for the native image size."""
    if options.intrinsics is None:
        return None
    fx, fy, cx, cy = (float(v) for v in options.intrinsics)
    lens = None
    if options.distortion is not None:
        lens = Lens("opencv", tuple(float(v) for v in options.distortion), DISTORTION_SOURCE)
    return Camera(fx, fy, cx, cy, None, OPTIONS_SOURCE, lens)


def warn_if_options_intrinsics(options: CaptureOptions, layout: str) -> None:
    """Log that ``options.intrinsics`` is ignored because the capture stores intrinsics."""
    if options.intrinsics is not None:
        logger.warning(
            "%s captures store their own intrinsics; CaptureOptions.intrinsics is ignored", layout
        )


def select(specs: list[FrameSpec], options: CaptureOptions) -> list[FrameSpec]:
    """Every ``stride``-th frame, at most ``max_frames`` of them."""
    kept = specs[:: options.stride]
    return kept if options.max_frames is None else kept[: options.max_frames]


def load_capture(
    listing: Listing, root: Path, layout: str, options: CaptureOptions, shown: str | None = None
) -> Capture:
    """Read the selected frames of a listing into a validated :class:`Capture`.

    Args:
        listing: the layout's frames and listing problems.
        root: the capture folder (messages name files relative to it).
        layout: the layout name stored in the capture.
        options: stride, max_frames, size and depth_trunc.
        shown: how to name the capture in messages and in ``Capture.root`` (default: ``root``;
            an archive's path when ``root`` is a temporary extraction folder).

    Returns:
        The validated capture.

    Raises:
        InputError: listing every problem of the listing and of the selected frames.
    """
    problems = list(listing.problems)
    frames: list[Frame] = []
    for _, frame, frame_problems in iter_frames(listing, root, options):
        problems.extend(frame_problems)
        if frame is not None:
            frames.append(frame)
    shown = shown or str(root)
    if frames or not problems:
        problems.extend(capture_problems(tuple(frames), shown))
    if problems:
        raise InputError(problems)
    logger.info("read %d frames of a %s capture from %s", len(frames), layout, shown)
    source, sparse = listing.depth_source, listing.sparse
    return Capture(tuple(frames), layout, shown, depth_source=source, sparse=sparse)


def iter_frames(
    listing: Listing, root: Path, options: CaptureOptions
) -> Iterator[tuple[FrameSpec, Frame | None, list[Problem]]]:
    """Read the selected frames one at a time (for checks that must not hold them all).

    Args:
        listing: the layout's frames.
        root: the capture folder.
        options: stride, max_frames, size and depth_trunc.

    Yields:
        ``(spec, frame, problems)`` per selected frame; ``frame`` is None when it could not be
        read (``problems`` says why). The listing's own problems are not repeated.
    """
    for spec in select(listing.specs, options):
        frame, problems = _load_frame(spec, listing.resample_depth, root, options)
        yield spec, frame, problems


def _load_frame(
    spec: FrameSpec, resample_depth: bool, root: Path, options: CaptureOptions
) -> tuple[Frame | None, list[Problem]]:
    problems: list[Problem] = []
    rgb = _collect(problems, read_spec_colour, spec, root)
    depth = _collect(problems, read_depth, spec, root) if spec.depth is not None else None
    if rgb is not None and spec.depth is None:  # RGB-only: missing everywhere
        depth = np.zeros(rgb.shape[:2], np.float32)
    if rgb is None or depth is None:
        return None, problems
    size = (int(rgb.shape[1]), int(rgb.shape[0]))
    try:
        depth = mask_low_confidence(depth, spec, root, options.min_confidence)
        depth = _depth_on_colour_grid(depth, size, spec, resample_depth, root)
        intrinsics = _native_intrinsics(spec.camera, size, rel(spec.rgb, root))
    except InputError as exc:
        return None, [*problems, *exc.problems]
    undistorted = None
    lens = spec.camera.lens
    if lens is not None and not lens.is_identity:
        problem = lens_problem(lens)
        if problem is not None:
            return None, [*problems, Problem(lens.source, problem)]
        undistorted = undistortion(lens, intrinsics)
        rgb, depth = undistort(rgb, depth, undistorted)
        intrinsics = undistorted.pinhole
    return _finish_frame(spec, rgb, depth, intrinsics, root, options, undistorted), problems


def _collect(
    problems: list[Problem], reader: Callable[[_T, Path], _R], target: _T, root: Path
) -> _R | None:
    try:
        return reader(target, root)
    except InputError as exc:
        problems.extend(exc.problems)
        return None


def read_colour(path: Path, root: Path) -> NDArray[np.uint8]:
    """A colour image as ``[H, W, 3]`` uint8 RGB (grey is replicated, alpha dropped)."""
    image = read_image(path, root=root)
    if image.dtype != np.uint8:
        raise InputError.single(rel(path, root), f"colour must be 8-bit, got {image.dtype}")
    if image.ndim == 2:
        image = np.repeat(image[:, :, None], 3, axis=2)
    return np.ascontiguousarray(image[:, :, :3])


def read_spec_colour(spec: FrameSpec, root: Path) -> NDArray[np.uint8]:
    """A frame's colour as ``[H, W, 3]`` uint8 RGB: its image, or its frame of a video."""
    if spec.rgb_frame is None:
        return read_colour(spec.rgb, root)
    from dcseg.io.video import read_video_frame

    return read_video_frame(spec.rgb, spec.rgb_frame, root)


def colour_size(spec: FrameSpec) -> tuple[int, int] | None:
    """``(width, height)`` of a frame's colour from its header (image or video container),
    or None when the header does not say."""
    if spec.rgb_frame is None:
        return images.image_size(spec.rgb)
    from dcseg.io.video import video_size

    return video_size(spec.rgb)


def colour_name(spec: FrameSpec, root: Path) -> str:
    """How a frame's colour is named in ``Frame.files``: the file, and a video's frame."""
    shown = rel(spec.rgb, root)
    return shown if spec.rgb_frame is None else f"{shown}#{spec.rgb_frame}"


def read_depth(spec: FrameSpec, root: Path) -> NDArray[np.float32]:
    """A depth file as ``[H, W]`` float32 metres, 0 = invalid (before any resampling)."""
    assert spec.depth is not None, "an RGB-only frame has no depth file"
    shown = rel(spec.depth, root)
    if spec.depth.suffix == RAW_DEPTH_SUFFIX:
        metres = read_lzfse_array(spec.depth, shown, _raw_size(spec), np.float32)
        return np.where(np.isfinite(metres) & (metres > 0), metres, np.float32(0.0))
    if spec.depth.suffix.lower() == ".exr":
        return read_exr_depth(spec.depth, shown)
    raw = read_npy(spec.depth, shown) if spec.depth.suffix == ".npy" else None
    if raw is None:
        raw = read_image(spec.depth, root=root)
    if raw.ndim != 2:
        raise InputError.single(
            shown, f"depth must be a single-channel image, got shape {tuple(raw.shape)}"
        )
    if np.issubdtype(raw.dtype, np.floating):
        return raw.astype(np.float32)
    if raw.dtype not in (np.uint16, np.uint32, np.int32):
        raise InputError.single(shown, f"depth must be 16-bit or float, got {raw.dtype}")
    metres = raw.astype(np.float32) / np.float32(spec.depth_scale)
    for value in spec.depth_invalid:
        metres[raw == value] = 0.0
    return metres


def depth_name(spec: FrameSpec, root: Path) -> str:
    """How messages name a frame's depth: its file, or that it has none (RGB-only)."""
    return "no depth (RGB-only)" if spec.depth is None else rel(spec.depth, root)


def _raw_size(spec: FrameSpec) -> tuple[int, int]:
    if spec.raw_size is None:  # pragma: no cover - layouts listing raw buffers set it
        raise InputError.single(str(spec.depth), "raw buffer without a size in the metadata")
    return spec.raw_size


def read_confidence(spec: FrameSpec, root: Path) -> NDArray[np.uint8]:
    """A frame's ARKit confidence map as ``[H, W]`` uint8 levels 0 (low), 1, 2 (high)."""
    assert spec.confidence is not None
    shown = rel(spec.confidence, root)
    if spec.confidence.suffix == RAW_CONFIDENCE_SUFFIX:
        levels = read_lzfse_array(spec.confidence, shown, _raw_size(spec), np.uint8)
    else:
        levels = read_image(spec.confidence, root=root)
        if levels.ndim != 2 or levels.dtype != np.uint8:
            raise InputError.single(
                shown,
                f"confidence must be a single-channel 8-bit image, got {levels.dtype} "
                f"of shape {tuple(levels.shape)}",
            )
    top = int(levels.max(initial=0))
    if top > 2:
        raise InputError.single(
            shown, f"confidence values must be ARKit levels 0, 1 or 2, found {top}"
        )
    return np.asarray(levels, dtype=np.uint8)


def mask_low_confidence(
    depth: NDArray[np.float32], spec: FrameSpec, root: Path, min_confidence: int
) -> NDArray[np.float32]:
    """``depth`` with pixels whose confidence is below ``min_confidence`` set to 0.

    Layouts without confidence (``spec.confidence`` None) and ``min_confidence`` 0 keep all.

    Raises:
        InputError: the confidence file is missing or unreadable, or has another size than
            the depth image.
    """
    if min_confidence <= 0 or spec.confidence is None:
        return depth
    levels = read_confidence(spec, root)
    if levels.shape != depth.shape:
        raise InputError.single(
            rel(spec.confidence, root),
            f"confidence size {levels.shape[1]}x{levels.shape[0]} does not match depth size "
            f"{depth.shape[1]}x{depth.shape[0]} ({depth_name(spec, root)})",
        )
    return np.where(levels >= min_confidence, depth, np.float32(0.0))


def _depth_on_colour_grid(
    depth: NDArray[np.float32],
    size: tuple[int, int],
    spec: FrameSpec,
    resample_depth: bool,
    root: Path,
) -> NDArray[np.float32]:
    depth_size = (int(depth.shape[1]), int(depth.shape[0]))
    if depth_size == size:
        return depth
    if not resample_depth:
        raise InputError.single(
            depth_name(spec, root),
            f"depth size {depth_size[0]}x{depth_size[1]} does not match "
            f"colour size {size[0]}x{size[1]} ({rel(spec.rgb, root)})",
        )
    if spec.depth_k is None:
        return resize_nearest(depth, size)
    camera = spec.camera
    return register_depth(depth, spec.depth_k, (camera.fx, camera.fy, camera.cx, camera.cy), size)


def _native_intrinsics(camera: Camera, size: tuple[int, int], rgb: str) -> Intrinsics:
    stated = camera.size or size
    if stated != size:
        raise InputError.single(
            camera.source,
            f"intrinsics are for {stated[0]}x{stated[1]} but the image {rgb} is "
            f"{size[0]}x{size[1]}",
        )
    return Intrinsics(camera.fx, camera.fy, camera.cx, camera.cy, size[0], size[1])


def _finish_frame(
    spec: FrameSpec,
    rgb: NDArray[np.uint8],
    depth: NDArray[np.float32],
    intrinsics: Intrinsics,
    root: Path,
    options: CaptureOptions,
    undistorted: Undistortion | None = None,
) -> Frame:
    if options.size is not None:
        _check_downscale(options.size, rgb, rel(spec.rgb, root))
        rgb = resize_area(rgb, options.size)
        depth = resize_nearest(depth, options.size)
        intrinsics = intrinsics.scaled(*options.size)
    if options.depth_trunc is not None:
        depth = np.where(depth > options.depth_trunc, np.float32(0.0), depth)
    files = {
        "rgb": colour_name(spec, root),
        "depth": depth_name(spec, root),
        "pose": spec.pose_source,
        "intrinsics": spec.camera.source,
    }
    if options.min_confidence > 0 and spec.confidence is not None:
        files["confidence"] = rel(spec.confidence, root)
    return Frame(
        name=spec.name,
        rgb=np.ascontiguousarray(rgb, dtype=np.uint8),
        depth=np.ascontiguousarray(depth, dtype=np.float32),
        intrinsics=intrinsics,
        c2w=np.array(spec.c2w, dtype=np.float64),
        files=files,
        undistortion=undistorted,
    )


def _check_downscale(size: tuple[int, int], rgb: NDArray[np.uint8], name: str) -> None:
    """Frames are only ever downscaled: a target size above the image's is refused."""
    width, height = int(rgb.shape[1]), int(rgb.shape[0])
    if size[0] > width or size[1] > height:
        raise InputError.single(
            name,
            f"target size {size[0]}x{size[1]} is larger than the image's {width}x{height}; "
            "frames are only ever downscaled (choose a smaller --size / options.capture.size)",
        )
