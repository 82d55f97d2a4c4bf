"""Whether camera poses are refined: detected from how well consecutive frames' depth agrees.

Poses from tracking (KinectFusion, ARKit, SLAM) are off by a fraction of a degree and a
centimetre or so per frame; refining them (:mod:`dcseg.reconstruct.poses`) recovers most of
what that costs, but on exact poses the corrections absorb some of the fit's own error and
cost held-out PSNR. :func:`dcseg.reconstruct.sensor.depth_agreement` projects each training
frame's depth into the next with the capture's poses and compares the median disagreement with
what the measured depth noise alone explains; misaligned poses push that ratio up, exact ones
keep it below 1 whatever the noise. Heavy depth noise hides a misalignment in that ratio, so
the systematic part of the disagreement is measured too: the relative rotation about the image
axes that it implies (``tilt_deg``, :func:`dcseg.reconstruct.sensor.tilt`), which noise averages
away. ``ReconstructConfig.pose_refinement`` ``auto`` refines when the ratio exceeds
:data:`THRESHOLD` or the tilt exceeds :data:`TILT_THRESHOLD`.
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


TILT_THRESHOLD = 0.15
"""``auto`` also refines when consecutive training frames' depth disagreement implies more than
this many degrees of relative rotation (``sensor.poses.tilt_deg``). Measured (benchmarks/README
"Real-sensor detection", 40 views 320x240, seeds 0-1): exact poses 0.027-0.036 at default noise,
0.077-0.093 at heavy noise, Replica room0 0.0004; 0.1 deg / 2 mm 0.064-0.071 (refining does not
pay there); 0.25 deg / 5 mm 0.137-0.179, at heavy noise 0.17-0.21; 0.5 deg / 1 cm 0.28-0.51, at
heavy noise 0.25-0.35 (where the ratio, 0.66 and 0.92, missed one of two)."""


def decide(mode: str, agreement: dict[str, Any] | None) -> bool:
    """Whether poses are refined: ``on``, ``off``, or ``auto`` when the agreement ratio
    exceeds :data:`THRESHOLD` (never without a measurement)."""
    if mode != "auto":
        return mode == "on"
    return detected(agreement)


def detected(agreement: dict[str, Any] | None) -> bool:
    """Whether ``agreement`` (:func:`dcseg.reconstruct.sensor.depth_agreement`) shows
    misaligned poses."""
    if agreement is None:
        return False
    ratio, tilt = agreement.get("ratio"), agreement.get("tilt_deg")
    return (ratio is not None and ratio > THRESHOLD) or (tilt is not None and tilt > TILT_THRESHOLD)


def detection_report(agreement: dict[str, Any] | None, mode: str, applied: bool) -> dict[str, Any]:
    """The ``sensor.poses`` entries of the decision: the threshold, whether the ratio exceeds
    it, the configured mode and whether poses are refined."""
    return {
        "threshold": THRESHOLD,
        "tilt_threshold_deg": TILT_THRESHOLD,
        "detected": detected(agreement),
        "mode": mode,
        "refined": applied,
    }


def log_detection(agreement: dict[str, Any] | None, report: dict[str, Any]) -> None:
    """One log line: the measured ratio and whether poses are refined, and why."""
    action = "refined" if report["refined"] else "kept as given"
    why = report["mode"] if report["mode"] != "auto" else "auto"
    ratio = None if agreement is None else agreement.get("ratio")
    if ratio is None or agreement is None:
        log.info("poses: depth agreement not measured; poses %s (%s)", action, why)
        return
    log.info(
        "poses: consecutive frames' depth disagrees by %.2f x what the noise explains "
        "(threshold %.2f) and implies %.3f deg of relative rotation (threshold %.2f), %s: "
        "poses %s (%s)",
        ratio,
        THRESHOLD,
        agreement.get("tilt_deg", float("nan")),
        TILT_THRESHOLD,
        "misaligned" if report["detected"] else "consistent",
        action,
        why,
    )
