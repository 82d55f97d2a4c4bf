"""Posed RGB-D capture readers: one entry point, the layout is detected from the files.

Supported layouts (see each module's docstring for the details):

* ``dcseg``: dcseg's own manifest, ``capture.json`` (:mod:`dcseg.io.captures.manifest`);
* ``scannet``: ScanNet export, ``color/`` + ``depth/`` + ``pose/`` (:mod:`.scannet`);
* ``replica``: NICE-SLAM Replica, ``results/`` + ``traj.txt`` (:mod:`.replica`);
* ``nerfstudio``: ``transforms.json`` with depth (:mod:`.nerfstudio`);
* ``7scenes``: Microsoft 7-Scenes, ``frame-*.color.*`` (:mod:`.sevenscenes`).

Example:
    >>> capture = read_capture("scan.zip", CaptureOptions(stride=5, size=(640, 480)))
    ... # doctest: +SKIP
"""

from __future__ import annotations

import logging
import tempfile
from collections.abc import Callable
from pathlib import Path

from dcseg.config import CaptureOptions
from dcseg.errors import InputError
from dcseg.io.archive import is_archive, safe_extract
from dcseg.io.captures import manifest, nerfstudio, replica, scannet, sevenscenes
from dcseg.io.captures.common import Listing, load_capture
from dcseg.types import Capture

__all__ = ["LAYOUTS", "detect_layout", "read_capture"]

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
    "7scenes": (sevenscenes.matches, sevenscenes.list_frames, "frame-*.color.*"),
}
"""Layout name -> (detector, frame lister, marker shown in messages), in detection order."""


def detect_layout(folder: Path) -> str:
    """The layout of a capture folder: the first of :data:`LAYOUTS` whose markers are present.

    Args:
        folder: the capture folder.

    Returns:
        One of ``"dcseg"``, ``"scannet"``, ``"replica"``, ``"nerfstudio"``, ``"7scenes"``.

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


def _read_folder(folder: Path, options: CaptureOptions, shown: str) -> Capture:
    layout = _detect(folder, shown)
    logger.debug("%s: detected the %s layout", shown, layout)
    listing = LAYOUTS[layout][1](folder, options)
    return load_capture(listing, folder, layout, options, shown=shown)


def read_capture(path: str | Path, options: CaptureOptions = _DEFAULT_OPTIONS) -> Capture:
    """Read a posed RGB-D capture from a folder or an archive of one.

    Args:
        path: a capture folder, or a ``.zip``/``.tar``/``.tar.gz``/``.tgz`` holding one (it is
            extracted safely into a temporary folder, removed once the frames are in memory;
            the capture's ``root`` is then the archive path).
        options: stride, max_frames, size, depth_trunc and intrinsics.

    Returns:
        The validated capture; frames hold their arrays in memory.

    Raises:
        InputError: listing every problem found (file relative to the capture root + reason).

    Example:
        >>> capture = read_capture("room0/", CaptureOptions(max_frames=10))  # doctest: +SKIP
    """
    path = Path(path)
    if path.is_dir():
        return _read_folder(path, options, str(path))
    if not path.exists():
        raise InputError.single(str(path), "does not exist")
    if not is_archive(path):
        raise InputError.single(
            str(path), "not a folder or a .zip/.tar/.tar.gz/.tgz archive of one"
        )
    with tempfile.TemporaryDirectory(prefix="dcseg-capture-") as tmp:
        folder = safe_extract(path, Path(tmp))
        return _read_folder(folder, options, str(path))
