"""``write_scene``: save a generated scene in the layouts dcseg's readers understand."""

from __future__ import annotations

import json
import logging
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from dcseg.synth.catalogue import RARE_CLASSES
from dcseg.synth.failures import LOOKALIKES
from dcseg.synth.generate import SynthScene, blurred_views
from dcseg.synth.semantic import CONFUSIONS

logger = logging.getLogger(__name__)


def write_scene(scene: SynthScene, out: Path) -> Path:
    """Write ``scene`` under ``out`` and return the path of ``scene.json``.

    Layout::

        capture.json, rgb/<stem>.png, depth/<stem>.png   dcseg capture manifest
        masks/agnostic/<stem>.json                       simulated SAM output (COCO RLE;
                                                         with a ``score`` per mask where the
                                                         error generator gives one)
        masks/semantic/<stem>.png                        simulated class maps (255 = none)
        vocabulary.txt                                   class names, one per line
        gt/points.ply                                    x y z label instance
        gt/semantic/<stem>.png, gt/instance/<stem>.png   perfect per-frame ground truth
                                                         (uint8 255 = none, uint16 0 = none)
        scene.json                                       config, vocabulary, instances, noise
                                                         parameters, timings

    Example:
        >>> write_scene(generate_scene(SynthConfig(frames=6)), Path("out"))  # doctest: +SKIP
    """
    from dcseg.io.captures.manifest import write_capture
    from dcseg.io.ground_truth import write_ground_truth_ply
    from dcseg.io.masks import write_agnostic_json
    from dcseg.io.semantic import write_semantic_png, write_vocabulary

    tick = time.perf_counter()
    out.mkdir(parents=True, exist_ok=True)
    write_capture(scene.capture, out)
    n_classes = len(scene.vocabulary)
    scores = scene.mask_scores or (None,) * len(scene.agnostic)
    for masks, semantic, score in zip(scene.agnostic, scene.semantic, scores, strict=True):
        path = out / "masks" / "agnostic" / f"{masks.name}.json"
        write_agnostic_json(path, masks)
        if score is not None:
            _add_scores(path, score)
        write_semantic_png(out / "masks" / "semantic" / f"{semantic.name}.png", semantic, n_classes)
    write_vocabulary(out / "vocabulary.txt", scene.vocabulary)
    write_ground_truth_ply(out / "gt" / "points.ply", scene.ground_truth)
    _write_gt_maps(scene, out / "gt")
    timings = dict(scene.timings, write=time.perf_counter() - tick)
    path = out / "scene.json"
    path.write_text(json.dumps(scene_summary(scene, timings), indent=1) + "\n", encoding="utf-8")
    logger.info("wrote %d frames to %s", len(scene.capture), out)
    return path


def _add_scores(path: Path, scores: tuple[float, ...]) -> None:
    """Give each record of a written mask file its detector ``score`` (in mask order)."""
    records = json.loads(path.read_text(encoding="utf-8"))
    if len(records) != len(scores):
        raise ValueError(f"{path}: {len(records)} masks but {len(scores)} scores")
    for record, score in zip(records, scores, strict=True):
        record["score"] = round(float(score), 4)
    path.write_text(json.dumps(records), encoding="utf-8")


def _write_gt_maps(scene: SynthScene, folder: Path) -> None:
    """Per-frame GT class maps (uint8, 255 = none) and instance maps (uint16, 0 = none)."""
    from dcseg.io.images import write_image

    for frame, classes, instances in zip(
        scene.capture.frames, scene.gt_semantic, scene.gt_instance, strict=True
    ):
        semantic = np.where(classes < 0, 255, classes).astype(np.uint8)
        write_image(folder / "semantic" / f"{frame.name}.png", semantic)
        write_image(
            folder / "instance" / f"{frame.name}.png", np.maximum(instances, 0).astype(np.uint16)
        )


def scene_summary(scene: SynthScene, timings: dict[str, float]) -> dict[str, Any]:
    """The content of ``scene.json``."""
    cfg = scene.config
    return {
        "seed": cfg.seed,
        "noise": cfg.noise,
        "error_model": cfg.segmenter(),
        "size": [cfg.width, cfg.height],
        "supersample": cfg.supersample,
        "frames": len(scene.capture),
        "vocabulary": list(scene.vocabulary.names),
        "rare_classes": list(RARE_CLASSES),
        "confusions": dict(CONFUSIONS),
        "lookalikes": {k: list(v) for k, v in LOOKALIKES.items()},
        "noise_level": asdict(cfg.level()),
        "pose_error": {"deg": cfg.pose_error_deg, "m": cfg.pose_error_m},
        "motion_blur_px": cfg.motion_blur_px,
        "exposure_spread": cfg.exposure_spread,
        "depth_shift_px": list(cfg.depth_shift_px),
        "motion_blur_share": cfg.motion_blur_share,
        "blurred_views": sorted(blurred_views(cfg)),
        "instances": [inst.record() for inst in scene.instances],
        "gt_points": len(scene.ground_truth.labels),
        "timings": {k: round(v, 3) for k, v in timings.items()},
    }
