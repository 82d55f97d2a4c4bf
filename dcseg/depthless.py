"""What a capture without depth (an RGB-only COLMAP model) changes, said once.

``dcseg validate``, ``reconstruction.json`` and the log all quote these, so the user reads the
same list wherever the capture shows up. Torch-free (the service's upload validation uses it).
"""

from __future__ import annotations

from typing import Any

__all__ = ["DEPTH_OFF", "RENDERED_DEPTH", "SCALE_NOTE", "depth_summary"]

DEPTH_OFF: tuple[str, ...] = (
    "initialisation from back-projected depth (the sparse points are used instead)",
    "depth loss (reconstruct.depth_weight)",
    "depth median filter and flying-pixel removal (depth_filter_window, drop_flying_pixels)",
    "surface priors (init_thickness, thickness_weight, centre_weight, opacity_weight, "
    "planar_depth)",
    "sensor depth report (noise model, missing depth, pose/depth agreement)",
    "held-out depth error (depth_mae and surface_depth_mae are null)",
)
"""The depth-dependent steps an RGB-only capture turns off."""

RENDERED_DEPTH = (
    "the later stages (mask 3D scales, the projection metrics' depth test, depth exports) use "
    "the surface depth rendered from the reconstruction"
)
"""What stands in for depth after the reconstruction."""

SCALE_NOTE = (
    "the model's scale is arbitrary (structure from motion alone): unless capture.pose_scale "
    "(--pose-scale) gives metres per model unit, options and outputs in metres are in the "
    "model's units (evaluate.depth_tol and max_distance, budget min_translation, assign "
    "support_min_extent, ring_plane_tol and ring_radius, voxel sizes, the scene extent)"
)
"""Why absolute sizes need care on an RGB-only COLMAP capture."""


def depth_summary(sparse_points: int | None) -> dict[str, Any]:
    """The fields a capture summary or report adds for an RGB-only capture (flat, so that
    ``dcseg validate`` prints one line each)."""
    return {
        "depth": "absent (RGB-only capture)",
        "sparse_points": sparse_points,
        "depth_off": list(DEPTH_OFF),
        "depth_instead": RENDERED_DEPTH,
        "scale": SCALE_NOTE,
    }
