"""Where a finished run's depth comes from: its own state, or the capture it was made from.

A run keeps every training view's depth (float16 metres) in ``state/views/<i>.npz`` and the
views' intrinsics and poses in ``state/views.json`` (layout: :mod:`dcseg.io.run_state`; read here
with numpy alone, one view at a time, without touching the cached blending weights). When a
run's state is gone, ``--capture PATH`` (or the capture path ``run.json`` recorded, if it
still exists) supplies the depth instead.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dcseg.config import CaptureOptions, capture_options
from dcseg.errors import InputError
from dcseg.io.poses import POSES_FILE

READABLE_VERSIONS = (1, 2)
"""The ``state/views.json`` versions this reader understands (those of :mod:`dcseg.io.run_state`;
both keep depth as float16 in the views' files)."""


@dataclass(frozen=True)
class DepthView:
    """One posed depth image; ``depth()`` reads it (only when fusion reaches the view).

    Attributes:
        name: the frame stem.
        K: ``[3, 3]`` intrinsics at the depth's resolution.
        c2w: ``[4, 4]`` camera-to-world pose, OpenCV axes.
        load: returns ``[H, W]`` float32 metres, 0 = invalid.
    """

    name: str
    K: NDArray[np.float64]
    c2w: NDArray[np.float64]
    load: Callable[[], NDArray[np.float32]]

    def depth(self) -> NDArray[np.float32]:
        return self.load()


def run_views(run: Path) -> list[DepthView] | None:
    """The depth views of ``run/state``, or None when the run holds none."""
    meta_path = run / "state" / "views.json"
    if not meta_path.is_file():
        return None
    try:
        body = json.loads(meta_path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as error:
        raise InputError.single(str(meta_path), f"cannot read the run's views: {error}") from None
    if body.get("version") not in READABLE_VERSIONS:
        reason = f"unsupported state version {body.get('version')!r} (expected 1 or 2)"
        raise InputError.single(str(meta_path), reason)
    folder = run / "state" / "views"
    views = [_state_view(folder / f"{i}.npz", meta) for i, meta in enumerate(body["views"])]
    present = [v for v in views if v is not None]
    return present if present and len(present) == len(views) else None


def _state_view(path: Path, meta: dict[str, Any]) -> DepthView | None:
    if not path.is_file():
        return None

    def load() -> NDArray[np.float32]:
        try:
            with np.load(path, allow_pickle=False) as data:
                depth: NDArray[np.float32] = np.asarray(data["depth"], dtype=np.float32)
        except (OSError, ValueError, KeyError) as error:
            raise InputError.single(str(path), f"cannot read the view's depth: {error}") from None
        return depth

    return DepthView(
        name=str(meta["name"]),
        K=np.asarray(meta["K"], dtype=np.float64),
        c2w=np.asarray(meta["c2w"], dtype=np.float64),
        load=load,
    )


def capture_views(path: Path, run: Path | None = None) -> list[DepthView]:
    """The frames of a capture (any layout :func:`dcseg.io.captures.read_capture` reads).

    Given the ``run`` made from it, the capture is read with the options the run recorded
    (``run.json`` ``capture_options``: size, intrinsics, depth truncation ...) and seen by the
    cameras its reconstruction fitted (``state/poses.json``: refined poses, depth registered
    to the colour camera, corrected intrinsics), so the depth lies where its Gaussians do.
    """
    from dcseg.io.captures import read_capture

    capture = read_capture(path, recorded_options(run))
    if not capture.has_depth:
        reason = (
            "an RGB-only capture has no depth to mesh: export from the run's state (its depth "
            "is rendered from the reconstruction), without --capture"
        )
        raise InputError.single(str(path), reason)
    cameras = None if run is None else run / "state" / POSES_FILE
    if cameras is not None and cameras.is_file():
        from dcseg.io.poses import read_cameras
        from dcseg.reconstruct.poses import with_cameras

        capture = with_cameras(capture, read_cameras(cameras))
    views = []
    for frame in capture.frames:
        k = frame.intrinsics
        K = np.array([[k.fx, 0.0, k.cx], [0.0, k.fy, k.cy], [0.0, 0.0, 1.0]])
        depth = np.asarray(frame.depth, dtype=np.float32)
        views.append(DepthView(frame.name, K, np.asarray(frame.c2w), _held(depth)))
    return views


def recorded_options(run: Path | None) -> CaptureOptions:
    """The capture options ``run.json`` recorded (``capture_options``); the defaults for a
    run recorded before it did, or without a run.

    Raises:
        InputError: the record is malformed (names ``run.json`` and the field).
    """
    record = None if run is None else _record(run)
    stored = record.get("capture_options") if isinstance(record, dict) else None
    if run is None or stored is None:
        return CaptureOptions()
    try:
        return capture_options(stored)
    except (TypeError, ValueError) as error:
        where = f"{run / 'run.json'}: capture_options"
        raise InputError.single(where, str(error)) from None


def _held(depth: NDArray[np.float32]) -> Callable[[], NDArray[np.float32]]:
    return lambda: depth


def depth_views(run: Path, capture: Path | None) -> list[DepthView]:
    """Depth for meshing ``run``: ``capture`` when given, else the run's state, else the capture
    ``run.json`` names.

    Raises:
        InputError: none of these holds depth (the message says to pass ``--capture``).
    """
    if capture is not None:
        return capture_views(capture, run)
    views = run_views(run)
    if views is not None:
        return views
    recorded = _recorded_capture(run)
    if recorded is not None and recorded.exists():
        return capture_views(recorded, run)
    reason = (
        "the run holds no depth (no state/views.json with views/<i>.npz)"
        + (f" and its capture {recorded} is gone" if recorded is not None else "")
        + "; give the capture it was made from with --capture PATH"
    )
    raise InputError.single(str(run), reason)


def _record(run: Path) -> Any:
    """``run.json``'s content, or None when it is missing or not JSON."""
    try:
        return json.loads((run / "run.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def _recorded_capture(run: Path) -> Path | None:
    record = _record(run)
    inputs = record.get("inputs") if isinstance(record, dict) else None
    value = inputs.get("capture") if isinstance(inputs, dict) else None
    return Path(value) if isinstance(value, str) and value else None


def poses(run: Path, capture: Path | None = None) -> NDArray[np.float64] | None:
    """``[V, 4, 4]`` camera-to-world poses of the run's views (for the up axis), or None."""
    views = run_views(run)
    if views is None and capture is not None:
        views = capture_views(capture, run)
    if not views:
        return None
    return np.stack([v.c2w for v in views])
