"""The ``frame.json`` the API's viewer page reads: which world axis is up in a job's scene.

Found as ``dcseg view`` finds a run's (:func:`dcseg.viewer.frame.frame_json`), in this order:

1. the job's own ``segment/frame.json`` artifact, when its segment stage wrote one;
2. the ``frame.json`` of an export of the job already made (``service.exports`` caches them;
   every export writes one, from the run's poses), so the viewer's up is the downloads' up;
3. derived from the segment stage's poses (``segment/state/views.json``) by the function the
   exports use: read in place from local storage, from the exports' fetched copy of the run
   with object storage (:func:`service.exports.run_getter`).
"""

from __future__ import annotations

from pathlib import Path

from dcseg.viewer.frame import FRAME_FILE, frame_json
from jobstore.settings import Settings
from service.artifacts import Artifact, list_artifacts
from service.export_child import RUN
from service.exports import cache_root, run_getter
from service.instances import JobFiles
from service.problems import ApiProblem

STORED = f"{RUN}/{FRAME_FILE}"
"""The artifact of a segment stage that states its frame itself."""


def job_frame(files: JobFiles, settings: Settings) -> bytes:
    """The body of ``frame.json`` for the succeeded job of ``files`` (404 when the job has no
    segment stage output: nothing to view)."""
    stored = list_artifacts(files.storage, files.tenant, files.job_id)
    if not any(a.name.startswith(RUN + "/") for a in stored):
        raise ApiProblem(
            404,
            f"job {files.job_id} has no segmented scene (its {RUN} stage wrote nothing)",
            slug="not-found",
            job_id=files.job_id,
        )
    own = next((a for a in stored if a.name == STORED), None)
    if own is not None:
        return _read(files, own)
    exported = exported_frame(cache_root(settings, files.job_id))
    if exported is not None:
        return exported
    return frame_json(run_getter(files.storage, files.tenant, files.job_id, settings)())


def exported_frame(root: Path) -> bytes | None:
    """The ``frame.json`` of a finished export cached under ``root`` (a job's exports folder),
    whole scene first; None when no export was made."""
    selections = sorted(root.glob("scene")) + sorted(root.glob("instance-*"))
    for selection in (s for s in selections if s.is_dir()):
        for variant in sorted(selection.iterdir()):
            frame = variant / "files" / FRAME_FILE
            finished = (variant / "manifest.json").is_file()  # renamed into place: whole
            if finished and not variant.name.startswith(".") and frame.is_file():
                return frame.read_bytes()
    return None


def _read(files: JobFiles, artifact: Artifact) -> bytes:
    if artifact.size == 0:
        return b""
    return b"".join(files.storage.read(files.tenant, artifact.item, 0, artifact.size - 1))
