"""Posed RGB-D capture readers: one entry point, the layout is detected from the files.

Supported layouts (see each module's docstring for the details):

* ``dcseg``: dcseg's own manifest, ``capture.json`` (:mod:`dcseg.io.captures.manifest`);
* ``scannet``: ScanNet export, ``color/`` + ``depth/`` + ``pose/`` (:mod:`.scannet`);
* ``replica``: NICE-SLAM Replica, ``results/`` + ``traj.txt`` (:mod:`.replica`);
* ``nerfstudio``: ``transforms.json`` with depth (:mod:`.nerfstudio`);
* ``record3d``: Record3D's ``.r3d`` export, ``metadata`` + ``rgbd/`` (:mod:`.record3d`);
* ``polycam``: Polycam's raw data export, ``keyframes/`` (:mod:`.polycam`);
* ``7scenes``: Microsoft 7-Scenes, ``frame-*.color.*`` (:mod:`.sevenscenes`).

Example:
    >>> capture = read_capture("scan.zip", CaptureOptions(stride=5, size=(640, 480)))
    ... # doctest: +SKIP
"""

from __future__ import annotations

import logging
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from dcseg.config import CaptureOptions
from dcseg.errors import InputError
from dcseg.io.archive import is_archive, safe_extract
from dcseg.io.captures import (
    manifest,
    nerfstudio,
    polycam,
    record3d,
    replica,
    scannet,
    sevenscenes,
)
from dcseg.io.captures.common import Listing, load_capture
from dcseg.types import Capture

__all__ = ["LAYOUTS", "CaptureListing", "detect_layout", "list_capture", "read_capture"]

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
    "polycam": (polycam.matches, polycam.list_frames, "keyframes/images+cameras/"),
    "7scenes": (sevenscenes.matches, sevenscenes.list_frames, "frame-*.color.*"),
}
"""Layout name -> (detector, frame lister, marker shown in messages), in detection order."""


def detect_layout(folder: Path) -> str:
    """The layout of a capture folder: the first of :data:`LAYOUTS` whose markers are present.

    Args:
        folder: the capture folder.

    Returns:
        One of the names of :data:`LAYOUTS` (``"dcseg"``, ``"scannet"``, ``"replica"``,
        ``"nerfstudio"``, ``"record3d"``, ``"polycam"``, ``"7scenes"``).

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
    return CaptureListing(folder, shown, layout, LAYOUTS[layout][1](folder, options))


@contextmanager
def list_capture(
    path: str | Path, options: CaptureOptions = _DEFAULT_OPTIONS
) -> Iterator[CaptureListing]:
    """List a capture's frames without decoding any image.

    An archive (or a Record3D ``.r3d`` file, a zip) is extracted safely into a temporary folder
    that lives as long as the block.

    Args:
        path: a capture folder or an archive of one.
        options: capture options (layouts read intrinsics and stride-independent settings).

    Yields:
        The listing; load its frames with :func:`dcseg.io.captures.common.iter_frames` or
        :func:`dcseg.io.captures.common.load_capture`.

    Raises:
        InputError: the path is missing, not a capture, or its layout cannot be listed.
    """
    path = Path(path)
    if path.is_dir():
        yield _list_folder(path, options, str(path))
        return
    if not path.exists():
        raise InputError.single(str(path), "does not exist")
    if not (is_archive(path) or path.suffix.lower() == record3d.R3D_SUFFIX):
        raise InputError.single(
            str(path), "not a folder, a .zip/.tar/.tar.gz/.tgz archive of one, or a .r3d file"
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
