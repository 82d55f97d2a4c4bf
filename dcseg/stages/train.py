"""The train stage (method step 2): blend-weight caches and affinity features of the scene.

Writes ``state/`` (Gaussians, features, per-view caches, previews: what re-clustering and
re-classifying reuse) and ``run.json`` (the inputs, the frame budget's choice, the
reconstruction's summary, the size rules and the resolved config). Skipped, saying why, when
the job has no class-agnostic masks (a capture-only upload is reconstructed, nothing more).
"""

from __future__ import annotations

import json
from dataclasses import asdict
from typing import TYPE_CHECKING, Any

from dcseg.errors import InputError
from dcseg.inputs import describe_missing
from dcseg.io.jsonfile import write_json
from dcseg.sizes import SceneSize, describe, resolve
from dcseg.stages.base import Stage, StageResult, StageRun
from dcseg.stages.reconstruct import REPORT, SCENE
from dcseg.stages.records import base_record

if TYPE_CHECKING:
    from dcseg.gaussians import Gaussians
    from dcseg.io.captures.plan import CapturePlan
    from dcseg.types import Capture

RUN_RECORD = "run.json"

NOT_IN_SUMMARY = ("views", "config", "capture", "size_rules", "versions", "peak_memory_mb")
"""Fields of ``reconstruction.json`` that ``run.json`` does not repeat under
``reconstruction`` (it has its own ``capture`` and ``size_rules``)."""


def train(run: StageRun) -> StageResult:
    """Cache blending weights and train affinity features on the reconstructed scene."""
    from dcseg.io.mask_formats.scores import min_scores
    from dcseg.io.masks import read_agnostic_masks
    from dcseg.io.run_output import SavedRun, preview_indices, save_state
    from dcseg.lens import of_frames, records, undistort_agnostic
    from dcseg.pipeline import train_scene
    from dcseg.reconstruct.job import device_of
    from dcseg.types import Vocabulary

    if run.inputs.agnostic_masks is None:
        missing = describe_missing(["agnostic_masks"])
        return StageResult("skipped", f"train: the job has no {missing}")
    capture, plan, gaussians = _scene(run)
    with run.clock.phase("read"):
        agnostic = read_agnostic_masks(
            run.inputs.agnostic_masks,
            size=plan.size,
            frames=plan.selection(),
            min_scores=min_scores(run.config.pipeline.affinity),
        )
        undistorted = of_frames(capture.frames)
        agnostic = undistort_agnostic(agnostic, undistorted)
    if not any(len(m) for m in agnostic.values()):
        raise InputError.single("class-agnostic masks", "no frame has any mask")
    size = SceneSize(len(capture), plan.size[0] * plan.size[1], len(gaussians))
    given = run.config.pipeline
    cfg = resolve(given, size)
    with run.clock.phase("train"):
        trained = train_scene(
            gaussians.to(device_of(run.device)),
            capture,
            agnostic,
            cfg,
            run.progress,
            cache_dir=run.out / "state",
        )
    previews = [(f.name, f.rgb) for f in (capture.frames[i] for i in preview_indices(len(capture)))]
    del capture  # the views' depth and weights are in state/ now; previews keep a few frames
    record = {
        "inputs": run.inputs.describe(),
        "capture": {**plan.summary(), "undistortion": records(undistorted)},
        "capture_options": asdict(run.config.capture),
        "reconstruction": _summary(run),
        "size_rules": describe(given, cfg, size),
    }
    saved = SavedRun(trained, {}, Vocabulary(()), previews, record)
    with run.clock.phase("write"):
        save_state(run.out, trained, {}, None, previews)
        _keep_cameras(run)
        write_json(run.out / RUN_RECORD, base_record(saved, cfg, run.clock))
    run.handover.trained = saved
    return StageResult("done", f"train: {run.clock.seconds.get('train', 0):.0f} s")


def _keep_cameras(run: StageRun) -> None:
    """Keep the reconstruction's ``poses.json`` (when its cameras differ from the capture's)
    as ``state/poses.json``: what reading the capture again needs to see it as the run did
    (:func:`dcseg.export.depth.capture_views`)."""
    from dcseg.io.folders import link_or_copy
    from dcseg.io.poses import POSES_FILE

    cameras = run.folder("reconstruct") / POSES_FILE
    if cameras.is_file():
        link_or_copy(cameras, run.out / "state" / POSES_FILE)


def _scene(run: StageRun) -> tuple[Capture, CapturePlan, Gaussians]:
    """The capture at the poses the Gaussians fit, its plan and the Gaussians: handed over
    by the reconstruct stage, or read from its files."""
    hand = run.handover
    capture, plan, gaussians = hand.capture, hand.plan, hand.gaussians
    hand.capture = hand.gaussians = None
    if capture is not None and plan is not None and gaussians is not None:
        return capture, plan, gaussians
    from dcseg.io.captures import read_planned
    from dcseg.io.ply import read_gaussians_ply
    from dcseg.io.poses import POSES_FILE, read_cameras
    from dcseg.reconstruct.poses import with_cameras

    scene = run.folder("reconstruct")
    with run.clock.phase("read"):
        capture, plan = read_planned(
            run.inputs.capture, run.config.capture, run.config.pipeline.budget
        )
        if (scene / POSES_FILE).is_file():
            capture = with_cameras(capture, read_cameras(scene / POSES_FILE))
        gaussians = read_gaussians_ply(scene / SCENE)
    return capture, plan, gaussians


def _summary(run: StageRun) -> dict[str, Any]:
    """The reconstruction's ``run.json`` summary, from its report."""
    report = json.loads((run.folder("reconstruct") / REPORT).read_text(encoding="utf-8"))
    return {k: v for k, v in report.items() if k not in NOT_IN_SUMMARY}


TRAIN = Stage(
    name="train",
    needs=("reconstruct",),
    inputs=("agnostic_masks",),
    outputs=("state", RUN_RECORD),
    config=("pipeline.cache", "pipeline.affinity"),
    parts={"cache": 0.1, "affinity": 0.9},
    run=train,
)
