"""Posed RGB-D capture readers: one entry point, the layout is detected from the files.

Supported layouts (see each module's docstring for the details):

* ``dcseg``: dcseg's own manifest, ``capture.json`` (:mod:`dcseg.io.captures.manifest`);
* ``scannet``: ScanNet export, ``color/`` + ``depth/`` + ``pose/`` (:mod:`.scannet`);
* ``replica``: NICE-SLAM Replica, ``results/`` + ``traj.txt`` (:mod:`.replica`);
* ``nerfstudio``: ``transforms.json`` with depth (:mod:`.nerfstudio`);
* ``record3d``: Record3D's ``.r3d`` export, ``metadata`` + ``rgbd/`` (:mod:`.record3d`);
* ``record3d-exr``: Record3D's "EXR + JPG" export, ``metadata.json`` + ``rgb/`` + ``depth/``;
* ``polycam``: Polycam's raw data export, ``keyframes/`` (:mod:`.polycam`);
* ``7scenes``: Microsoft 7-Scenes, ``frame-*.color.*`` (:mod:`.sevenscenes`);
* ``tum``: TUM RGB-D, ``rgb.txt`` + ``depth.txt`` + ``groundtruth.txt`` (:mod:`.tum`);
* ``colmap``: a COLMAP sparse model, ``sparse/0/cameras`` + ``images``, with depth or RGB-only
  (:mod:`.colmap`);
* ``redwood``: Redwood / Open3D, ``image|rgb|color/`` + ``depth/`` + a ``.log`` (:mod:`.redwood`);
* ``arkitscenes``: Apple ARKitScenes, ``lowres_wide/`` + ``lowres_wide.traj`` (:mod:`.arkitscenes`);
* ``scannetpp``: ScanNet++ iPhone, ``rgb/`` + ``pose_intrinsic_imu.json`` (:mod:`.scannetpp`);
* ``scannet-sens``: a raw ScanNet ``.sens`` file, given like an archive (:mod:`.sens`);
* ``stray``: Stray Scanner, ``odometry.csv`` + ``camera_matrix.csv`` + ``rgb.mp4`` + ``depth/``
  (:mod:`.stray`).

Example:
    >>> capture = read_capture("scan.zip", CaptureOptions(stride=5, size=(640, 480)))
    ... # doctest: +SKIP
"""

from __future__ import annotations

import logging
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from dcseg.config import NATIVE_BUDGET, CaptureOptions, FrameBudget
from dcseg.errors import InputError
from dcseg.io.archive import is_archive, safe_extract
from dcseg.io.captures import (
    arkitscenes,
    colmap,
    manifest,
    nerfstudio,
    polycam,
    record3d,
    redwood,
    replica,
    scannet,
    scannetpp,
    sens,
    sevenscenes,
    stray,
    tum,
)
from dcseg.io.captures.common import (
    FrameSpec,
    Listing,
    colour_size,
    load_capture,
    read_spec_colour,
    rel,
    scale_poses,
    select,
)
from dcseg.io.captures.plan import CaptureMeta, CapturePlan, plan_capture
from dcseg.io.video import close_videos
from dcseg.types import Capture

__all__ = [
    "LAYOUTS",
    "CaptureListing",
    "detect_layout",
    "list_capture",
    "read_capture",
    "read_planned",
]

logger = logging.getLogger(__name__)

_Lister = Callable[[Path, CaptureOptions], Listing]
_DEFAULT_OPTIONS = CaptureOptions()


def _has_manifest(root: Path) -> bool:
    return (root / manifest.MANIFEST).is_file()


LAYOUTS: dict[str, tuple[Callable[[Path], bool], _Lister, str]] = {
    "dcseg": (_has_manifest, manifest.list_frames, "capture.json"),
    "scannet": (scannet.matches, scannet.list_frames, "color/+depth/+pose/"),
    "replica": (replica.matches, replica.list_frames, "results/+traj.txt"),
    "nerfstudio": (nerfstudio.matches, nerfstudio.list_frames, "transforms.json"),
    "record3d": (record3d.matches, record3d.list_frames, "metadata+rgbd/"),
    "record3d-exr": (record3d.matches_exr, record3d.list_exr_frames, "metadata.json+rgb/+depth/"),
    "polycam": (polycam.matches, polycam.list_frames, "keyframes/images+cameras/"),
    "7scenes": (sevenscenes.matches, sevenscenes.list_frames, "frame-*.color.*"),
    "tum": (tum.matches, tum.list_frames, "rgb.txt+depth.txt"),
    "colmap": (colmap.matches, colmap.list_frames, "sparse/0/cameras+images.bin|txt"),
    "redwood": (redwood.matches, redwood.list_frames, "image|rgb|color/+depth/+*.log"),
    "arkitscenes": (arkitscenes.matches, arkitscenes.list_frames, "lowres_wide/+lowres_wide.traj"),
    "scannetpp": (scannetpp.matches, scannetpp.list_frames, "rgb/+pose_intrinsic_imu.json"),
    "stray": (stray.matches, stray.list_frames, "odometry.csv+camera_matrix.csv+rgb.mp4+depth/"),
}
"""Layout name -> (detector, frame lister, marker shown in messages), in detection order."""


def detect_layout(folder: Path) -> str:
    """The layout of a capture folder: the first of :data:`LAYOUTS` whose markers are present.

    Args:
        folder: the capture folder.

    Returns:
        One of the names of :data:`LAYOUTS` (``"dcseg"``, ``"scannet"``, ``"replica"``,
        ``"nerfstudio"``, ``"record3d"``, ``"record3d-exr"``, ``"polycam"``, ``"7scenes"``,
        ``"tum"``, ``"colmap"``, ``"redwood"``, ``"arkitscenes"``,
        ``"scannetpp"``, ``"stray"``).

    Raises:
        InputError: no layout's markers are found.
    """
    return _detect(folder, str(folder))


def _detect(folder: Path, shown: str) -> str:
    for name, (detector, _, _) in LAYOUTS.items():
        if detector(folder):
            return name
    expected = ", ".join(marker for _, _, marker in LAYOUTS.values())
    raise InputError.single(
        shown, f"no capture layout recognised in {shown}: expected one of {expected}"
    )


@dataclass(frozen=True)
class CaptureListing:
    """A capture's frames as listed by its layout, before any image is decoded.

    Attributes:
        folder: the capture folder (a temporary extraction folder for archives).
        shown: how messages name the capture (the path given, e.g. the archive).
        layout: the detected layout name.
        listing: the frame specs and the problems found while listing them.
    """

    folder: Path
    shown: str
    layout: str
    listing: Listing


def _list_folder(folder: Path, options: CaptureOptions, shown: str) -> CaptureListing:
    layout = _detect(folder, shown)
    logger.debug("%s: detected the %s layout", shown, layout)
    listing = scale_poses(LAYOUTS[layout][1](folder, options), options.pose_scale)
    return CaptureListing(folder, shown, layout, listing)


@contextmanager
def list_capture(
    path: str | Path, options: CaptureOptions = _DEFAULT_OPTIONS
) -> Iterator[CaptureListing]:
    """List a capture's frames without decoding any image.

    An archive (or a Record3D ``.r3d`` file, a zip) is extracted safely into a temporary folder
    that lives as long as the block; a ScanNet ``.sens`` file is decoded into one
    (:mod:`.sens`, layout ``scannet-sens``).

    Args:
        path: a capture folder or an archive of one.
        options: capture options (layouts read intrinsics and stride-independent settings).

    Yields:
        The listing; load its frames with :func:`dcseg.io.captures.common.iter_frames` or
        :func:`dcseg.io.captures.common.load_capture`.

    Raises:
        InputError: the path is missing, not a capture, or its layout cannot be listed.
    """
    with _listed(Path(path), options) as listed:
        try:
            yield listed
        finally:  # a video decoder holds its file open (an archive's temporary copy)
            close_videos(listed.folder)


@contextmanager
def _listed(path: Path, options: CaptureOptions) -> Iterator[CaptureListing]:
    if path.is_dir():
        yield _list_folder(path, options, str(path))
        return
    if not path.exists():
        raise InputError.single(str(path), "does not exist")
    if path.suffix.lower() == sens.SENS_SUFFIX:
        with tempfile.TemporaryDirectory(prefix="dcseg-capture-") as tmp:
            folder = sens.extract(path, Path(tmp))
            listing = scale_poses(scannet.list_frames(folder, options), options.pose_scale)
            yield CaptureListing(folder, str(path), "scannet-sens", listing)
        return
    if not (is_archive(path) or path.suffix.lower() == record3d.R3D_SUFFIX):
        raise InputError.single(
            str(path),
            "not a folder, a .zip/.tar/.tar.gz/.tgz archive of one, or a .r3d file "
            "or a ScanNet .sens file",
        )
    with tempfile.TemporaryDirectory(prefix="dcseg-capture-") as tmp:
        folder = safe_extract(path, Path(tmp))
        yield _list_folder(folder, options, str(path))


def read_capture(path: str | Path, options: CaptureOptions = _DEFAULT_OPTIONS) -> Capture:
    """Read a posed RGB-D capture from a folder or an archive of one.

    Args:
        path: a capture folder, a Record3D ``.r3d`` file, or a ``.zip``/``.tar``/``.tar.gz``/
            ``.tgz`` holding a capture folder (it is
            extracted safely into a temporary folder, removed once the frames are in memory;
            the capture's ``root`` is then the archive path).
        options: stride, max_frames, size, depth_trunc, intrinsics and min_confidence.

    Returns:
        The validated capture; frames hold their arrays in memory.

    Raises:
        InputError: listing every problem found (file relative to the capture root + reason).

    Example:
        >>> capture = read_capture("room0/", CaptureOptions(max_frames=10))  # doctest: +SKIP
    """
    with list_capture(path, options) as listed:
        return load_capture(
            listed.listing, listed.folder, listed.layout, options, shown=listed.shown
        )


def read_planned(
    path: str | Path, options: CaptureOptions, budget: FrameBudget = NATIVE_BUDGET
) -> tuple[Capture, CapturePlan]:
    """Read the frames ``budget`` selects, at its working resolution (only those are decoded).

    The plan (:func:`dcseg.io.captures.plan.plan_capture`) is made from the listing: the poses
    and the first frame's image header. ``options.size``, when given, is the capture's
    resolution (the one outputs are written at); the budget may downscale it further.

    Returns:
        The capture (selected frames at ``plan.size``) and the plan.

    Raises:
        InputError: as :func:`read_capture`; also a ``size`` above the frames' own.
    """
    with list_capture(path, options) as listed:
        specs = select(listed.listing.specs, options)
        if not specs:  # nothing to plan: the loader reports why
            capture = load_capture(listed.listing, listed.folder, listed.layout, options)
            return capture, plan_capture(CaptureMeta((), np.zeros((0, 4, 4)), (1, 1)), budget)
        size = _output_size(specs[0], listed.folder, options)
        poses = np.stack([np.asarray(s.c2w, dtype=np.float64) for s in specs])
        plan = plan_capture(CaptureMeta(tuple(s.name for s in specs), poses, size), budget)
        logger.info("%s: %s", listed.shown, plan.describe())
        chosen = replace(listed.listing, specs=[specs[i] for i in plan.frames])
        read = replace(options, stride=1, max_frames=None, size=_read_size(plan, options))
        capture = load_capture(chosen, listed.folder, listed.layout, read, shown=listed.shown)
    return capture, plan


def _output_size(spec: FrameSpec, root: Path, options: CaptureOptions) -> tuple[int, int]:
    """``options.size`` or the first frame's own size; refuses upscaling, naming the file."""
    native = colour_size(spec)
    if native is None:  # a format whose header we do not parse: decode the one frame
        rgb = read_spec_colour(spec, root)
        native = (int(rgb.shape[1]), int(rgb.shape[0]))
    size = options.size
    if size is None:
        return native
    if size[0] > native[0] or size[1] > native[1]:
        raise InputError.single(
            rel(spec.rgb, root),
            f"target size {size[0]}x{size[1]} is larger than the image's "
            f"{native[0]}x{native[1]}; frames are only ever downscaled "
            "(choose a smaller --size / options.capture.size)",
        )
    return size


def _read_size(plan: CapturePlan, options: CaptureOptions) -> tuple[int, int] | None:
    """The size given to the loader: None at native size (frames are then checked to agree)."""
    if plan.factor == 1 and options.size is None:
        return None
    return plan.size
