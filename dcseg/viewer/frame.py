"""The run's coordinate frame for the viewer: ``frame.json``, as the exports write it.

The page sets the camera's up axis from this description instead of assuming ``+z``. A run
folder holding a ``frame.json`` (an export written into it, possibly from ``--capture`` poses)
is served as it is; otherwise the description is derived from the run's own poses
(``state/views.json``) by the function the exports use (:func:`dcseg.export.frame.describe_frame`),
so the viewer and ``dcseg export`` agree on which axis is up.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

from dcseg.errors import InputError
from dcseg.export.depth import poses
from dcseg.export.frame import describe_frame

log = logging.getLogger(__name__)

FRAME_FILE = "frame.json"
"""The name the frame description is served under (the exports' sidecar name)."""


def frame_json(run: Path) -> bytes:
    """The body of ``frame.json`` for ``run``: its own file, else derived from its poses
    (no poses, or unreadable ones, give the description of a run without poses: no up axis)."""
    own = run / FRAME_FILE
    if own.is_file():
        return own.read_bytes()
    try:
        c2w = poses(run)
    except InputError as error:  # a broken state must not keep the scene from being shown
        log.warning("no up axis from the run's poses: %s", error)
        c2w = None
    return (json.dumps(describe_frame(c2w, []), indent=2) + "\n").encode("utf-8")
