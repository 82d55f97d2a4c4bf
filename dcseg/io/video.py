"""Frames of a video file (Stray Scanner's ``rgb.mp4``), decoded with OpenCV's FFmpeg backend.

A capture layout may name a video frame as a frame's colour (:attr:`FrameSpec.rgb_frame
<dcseg.io.captures.common.FrameSpec>`): ``read_video_frame(path, index)`` decodes frame
``index`` (0-based, in decoding order). Frames are read in capture order, so one decoder per
file is kept open and moved forward; asking for an earlier frame reopens the file. Each decoded
frame is counted against the current :func:`dcseg.io.images.pixel_budget` and refused above
:data:`dcseg.io.images.MAX_PIXELS`, as images are. :func:`close_videos` releases the decoder.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from dcseg.errors import InputError
from dcseg.io.images import MAX_PIXELS, charge_pixels, display_path

__all__ = [
    "VIDEO_SUFFIXES",
    "close_videos",
    "open_videos",
    "read_video_frame",
    "video_frames",
    "video_size",
]

VIDEO_SUFFIXES = (".mp4", ".mov", ".m4v")
"""File suffixes read as videos."""


@dataclass
class _Decoder:
    """An open video and the index of the frame its next ``read`` gives."""

    path: Path
    capture: cv2.VideoCapture
    next_index: int = 0


_LOCK = threading.Lock()
_OPEN: dict[str, _Decoder] = {}
"""Open decoders by file, the least recently used first."""
MAX_OPEN = 4
"""At most this many videos stay open (captures read at once, e.g. by the API and a worker)."""


def _open(path: Path, shown: str) -> cv2.VideoCapture:
    if not path.is_file():
        raise InputError.single(shown, "missing")
    capture = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG)
    if not capture.isOpened():
        capture.release()
        raise InputError.single(shown, "cannot open video (corrupt, or a codec FFmpeg lacks)")
    return capture


def video_size(path: Path) -> tuple[int, int] | None:
    """``(width, height)`` of a video's frames from its container, or None if unreadable."""
    try:
        capture = _open(path, str(path))
    except InputError:
        return None
    try:
        width = int(capture.get(cv2.CAP_PROP_FRAME_WIDTH))
        height = int(capture.get(cv2.CAP_PROP_FRAME_HEIGHT))
    finally:
        capture.release()
    return (width, height) if width > 0 and height > 0 else None


def video_frames(path: Path, root: Path | None = None) -> int:
    """How many frames a video holds, as its container states.

    Raises:
        InputError: the file is missing or cannot be opened.
    """
    capture = _open(path, display_path(path, root))
    try:
        return max(int(capture.get(cv2.CAP_PROP_FRAME_COUNT)), 0)
    finally:
        capture.release()


def read_video_frame(path: Path, index: int, root: Path | None = None) -> NDArray[np.uint8]:
    """Frame ``index`` of a video as ``[H, W, 3]`` uint8 RGB.

    Raises:
        InputError: the file is missing or unreadable, holds fewer frames, a frame is larger
            than :data:`MAX_PIXELS`, or the pixel budget is exceeded; naming the file and frame.
    """
    shown = f"{display_path(path, root)} (frame {index})"
    with _LOCK:
        decoder = _decoder(path, index, display_path(path, root))
        while decoder.next_index < index:
            if not decoder.capture.grab():
                break
            decoder.next_index += 1
        ok, frame = decoder.capture.read() if decoder.next_index == index else (False, None)
        decoder.next_index += 1
    if not ok or frame is None:
        raise InputError.single(shown, f"the video has no frame {index} (it ends earlier)")
    height, width = int(frame.shape[0]), int(frame.shape[1])
    if width * height > MAX_PIXELS:
        reason = f"frame is {width}x{height} pixels, above the limit of {MAX_PIXELS:,} pixels"
        raise InputError.single(shown, reason)
    charge_pixels(width * height, shown)
    if frame.ndim == 2:
        frame = np.repeat(frame[:, :, None], 3, axis=2)
    return np.ascontiguousarray(frame[:, :, 2::-1], dtype=np.uint8)


def open_videos(under: Path | None = None) -> list[Path]:
    """The videos in folder ``under`` (None = any) whose decoder is open."""
    root = None if under is None else under.resolve()
    with _LOCK:
        return [d.path for d in _OPEN.values() if root is None or d.path.is_relative_to(root)]


def close_videos(under: Path | None = None) -> None:
    """Release the open decoders of videos in folder ``under`` (None = all), so their files
    may be deleted and their space freed (:func:`dcseg.io.captures.list_capture` calls this
    for its capture when its block ends)."""
    root = None if under is None else under.resolve()
    with _LOCK:
        for key in [k for k, d in _OPEN.items() if root is None or d.path.is_relative_to(root)]:
            _OPEN.pop(key).capture.release()


def _decoder(path: Path, index: int, shown: str) -> _Decoder:
    """The open decoder of ``path`` positioned at or before ``index`` (reopened if needed)."""
    try:
        stat = path.stat()
    except OSError:
        raise InputError.single(shown, "missing") from None
    resolved = path.resolve()
    key = f"{resolved}:{stat.st_size}:{stat.st_mtime_ns}"  # a rewritten file reopens
    decoder = _OPEN.pop(key, None)
    if decoder is not None and decoder.next_index > index:
        decoder.capture.release()
        decoder = None
    if decoder is None:
        decoder = _Decoder(resolved, _open(path, shown))
    _OPEN[key] = decoder  # the most recently used last
    while len(_OPEN) > MAX_OPEN:
        _OPEN.pop(next(iter(_OPEN))).capture.release()
    return decoder
