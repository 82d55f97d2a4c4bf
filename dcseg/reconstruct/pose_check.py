"""Whether camera poses are refined: detected from how well consecutive frames' depth agrees.

Poses from tracking (KinectFusion, ARKit, SLAM) are off by a fraction of a degree and a
centimetre or so per frame; refining them (:mod:`dcseg.reconstruct.poses`) recovers most of
what that costs, but on exact poses the corrections absorb some of the fit's own error and
cost held-out PSNR. :func:`dcseg.reconstruct.sensor.depth_agreement` projects each training
frame's depth into the next with the capture's poses and compares the median disagreement with
what the measured depth noise alone explains; misaligned poses push that ratio up, exact ones
keep it below 1 whatever the noise. ``ReconstructConfig.pose_refinement`` ``auto`` refines
when the ratio exceeds :data:`THRESHOLD`.
"""

from __future__ import annotations

import logging
from typing import Any

log = logging.getLogger(__name__)

MODES = ("auto", "on", "off")
"""``ReconstructConfig.pose_refinement``: refine when detected, always, never."""

THRESHOLD = 0.8
"""``auto`` refines when consecutive training frames' depth disagrees by more than this many
times what the noise explains (``sensor.poses.ratio``). Measured (benchmarks/README "Pose
refinement: auto"): exact poses 0.41-0.46 (synthetic layouts 0-3, 40 views 320x240,
default noise), Replica room0 0.29; 0.1 deg / 2 mm per frame 0.52-0.56 (where refining
does not pay), 0.5 deg / 1 cm 1.13-1.19; the slambook2 Kinect v1 sample 1.50."""


def decide(mode: str, agreement: dict[str, Any] | None) -> bool:
    """Whether poses are refined: ``on``, ``off``, or ``auto`` when the agreement ratio
    exceeds :data:`THRESHOLD` (never without a measurement)."""
    if mode != "auto":
        return mode == "on"
    return detected(agreement)


def detected(agreement: dict[str, Any] | None) -> bool:
    """Whether ``agreement`` (:func:`dcseg.reconstruct.sensor.depth_agreement`) shows
    misaligned poses."""
    ratio = None if agreement is None else agreement.get("ratio")
    return ratio is not None and ratio > THRESHOLD


def detection_report(agreement: dict[str, Any] | None, mode: str, applied: bool) -> dict[str, Any]:
    """The ``sensor.poses`` entries of the decision: the threshold, whether the ratio exceeds
    it, the configured mode and whether poses are refined."""
    return {
        "threshold": THRESHOLD,
        "detected": detected(agreement),
        "mode": mode,
        "refined": applied,
    }


def log_detection(agreement: dict[str, Any] | None, report: dict[str, Any]) -> None:
    """One log line: the measured ratio and whether poses are refined, and why."""
    action = "refined" if report["refined"] else "kept as given"
    why = report["mode"] if report["mode"] != "auto" else "auto"
    ratio = None if agreement is None else agreement.get("ratio")
    if ratio is None:
        log.info("poses: depth agreement not measured; poses %s (%s)", action, why)
        return
    log.info(
        "poses: consecutive frames' depth disagrees by %.2f x what the noise explains "
        "(threshold %.2f, %s): poses %s (%s)",
        ratio,
        THRESHOLD,
        "misaligned" if report["detected"] else "consistent",
        action,
        why,
    )
