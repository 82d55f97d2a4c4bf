"""The reconstruct stage (method step 1): Gaussians fitted to the posed RGB-D frames.

Writes ``scene.ply`` (3DGS layout), ``reconstruction.json`` (held-out metrics, the frame
budget's choice, the size rules, timings, the detected sensor effects and, when the job has
ground-truth surface points, the geometry: centre-to-surface distance and coverage) and, when
its cameras differ from the capture's (refined poses, depth registered by another colour
camera, corrected intrinsics), ``poses.json``. A job given a scene
(:attr:`~dcseg.inputs.RunInputs.scene`) links it (and its ``poses.json``) instead.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import TYPE_CHECKING, Any

from dcseg import __version__
from dcseg.errors import InputError
from dcseg.io.folders import link_or_copy
from dcseg.io.jsonfile import write_json
from dcseg.io.poses import POSES_FILE
from dcseg.progress import steps
from dcseg.sizes import SceneSize, reconstruct_record
from dcseg.stages.base import Stage, StageResult, StageRun, peak_mb
from dcseg.stages.records import versions

if TYPE_CHECKING:
    from dcseg.types import Capture

log = logging.getLogger(__name__)

SCENE = "scene.ply"
REPORT = "reconstruction.json"


def reconstruct(run: StageRun) -> StageResult:
    """Read the planned frames, fit Gaussians (or take the given scene), write them."""
    from dcseg.io.captures import read_planned
    from dcseg.reconstruct.job import device_of

    cfg = run.config.pipeline
    where = device_of(run.device)  # a bad device is refused before the capture is read
    with run.clock.phase("read"):
        capture, plan = read_planned(run.inputs.capture, run.config.capture, cfg.budget)
    size = SceneSize(views=len(capture), pixels=plan.size[0] * plan.size[1])
    if run.inputs.scene is not None:
        report = _given(run, run.inputs.scene, capture)
    else:
        report = _fitted(run, capture, size, where)
    report.update(capture=plan.summary(), device=str(where))
    report["peak_memory_mb"] = peak_mb()
    write_json(run.out / REPORT, report)
    run.handover.plan = plan
    return StageResult("done", f"reconstruct: {report['gaussians']} Gaussians")


def _fitted(run: StageRun, capture: Capture, size: SceneSize, where: Any) -> dict[str, Any]:
    """Fit the Gaussians on ``where`` and write them (and refined poses) into ``run.out``."""
    from dcseg.io.ply import write_gaussians_ply
    from dcseg.io.poses import write_poses
    from dcseg.reconstruct.job import reconstruct_scene
    from dcseg.reconstruct.poses import with_cameras

    pipeline = run.config.pipeline
    cfg, rules_record = reconstruct_record(pipeline.reconstruct, pipeline.rules, size)
    with run.clock.phase("reconstruct"):
        gaussians, report, cameras = reconstruct_scene(
            capture, cfg, where, steps(run.progress, "reconstruct")
        )
    report["size_rules"] = rules_record
    if run.inputs.ground_truth is not None:
        with run.clock.phase("geometry"):
            report["geometry"] = _geometry(gaussians, run.inputs.ground_truth)
    with run.clock.phase("write"):
        write_gaussians_ply(run.out / SCENE, gaussians)
        refinement = report.get("pose_refinement")
        if refinement is not None:  # the poses go to their own file, beside the scene
            refinement.pop("poses")
            refinement["file"] = POSES_FILE
        if cameras is not None:
            write_poses(
                run.out / POSES_FILE, cameras.poses, cameras.registration, cameras.intrinsics
            )
            capture = with_cameras(capture, cameras)
        else:  # an earlier scene's cameras would be read with this scene
            (run.out / POSES_FILE).unlink(missing_ok=True)
    report["seconds"] = {**report["seconds"], **_phases(run, ("read", "geometry", "write"))}
    report["versions"] = {"dcseg": __version__, **versions()}
    run.handover.capture, run.handover.gaussians = capture, gaussians
    return report


def _geometry(gaussians: Any, ground_truth: Path) -> dict[str, Any]:
    """:func:`dcseg.evaluate.surface.geometry_report` of ``gaussians`` against the ground
    truth's points (their labels play no part)."""
    from dcseg.evaluate.surface import geometry_report
    from dcseg.io.ground_truth import read_ground_truth_points

    surface = read_ground_truth_points(ground_truth)
    means = gaussians.means.detach().cpu().numpy()
    opacities = gaussians.opacities().detach().cpu().numpy()
    report = geometry_report(means, opacities, surface)
    log.info(
        "geometry: opaque centres %.1f mm from the surface (median); %.1f %% of it without an "
        "opaque centre within %.0f cm",
        report["centre_to_surface"]["median"] * 1000,
        report["coverage"]["gap"] * 100,
        report["coverage_radius"] * 100,
    )
    report["ground_truth"] = str(ground_truth)
    return report


def _given(run: StageRun, scene: Path, capture: Capture) -> dict[str, Any]:
    """Link a given scene (and the refined poses beside it) into ``run.out``."""
    from dcseg.io.ply import read_gaussians_ply
    from dcseg.io.poses import read_cameras
    from dcseg.reconstruct.poses import with_cameras

    report: dict[str, Any] = {"scene": str(scene)}
    gaussians = read_gaussians_ply(scene)
    link_or_copy(scene, run.out / SCENE)
    poses_file = scene.parent / POSES_FILE
    if poses_file.is_file():
        cameras = read_cameras(poses_file)
        missing = [f.name for f in capture.frames if f.name not in cameras.poses]
        if missing:
            reason = (
                f"has the cameras the scene was fitted to but none for {len(missing)} of the "
                f"capture's frames (first: {missing[0]}); reconstruct with the same frames "
                "and budget"
            )
            raise InputError.single(str(poses_file), reason)
        link_or_copy(poses_file, run.out / POSES_FILE)
        capture = with_cameras(capture, cameras)
        report["pose_refinement"] = {"poses_from": str(scene.parent)}
    report["gaussians"] = len(gaussians)
    run.handover.capture, run.handover.gaussians = capture, gaussians
    return report


def _phases(run: StageRun, names: tuple[str, ...]) -> dict[str, float]:
    return {name: run.clock.seconds[name] for name in names if name in run.clock.seconds}


RECONSTRUCT = Stage(
    name="reconstruct",
    needs=(),
    inputs=("capture", "ground_truth"),
    outputs=(SCENE, REPORT, POSES_FILE),
    config=("capture", "pipeline.budget", "pipeline.rules", "pipeline.reconstruct"),
    parts={"reconstruct": 1.0},
    run=reconstruct,
)
