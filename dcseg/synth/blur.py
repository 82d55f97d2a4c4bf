"""Motion blur of a rendered view: the camera moving while the shutter is open.

A static scene seen by a moving camera blurs along the optical flow the motion induces. The
flow of every pixel comes from its true depth, back-projected from this pose and projected
into the next pose of the trajectory; it is scaled so that its median length is the asked
blur length, and the image is averaged over samples along it, centred on the pose (the pose is
the middle of the exposure). Disocclusions are approximated (the sample is read from this
view's own image), as a backward warp does.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from numpy.typing import NDArray

MAX_BLUR_PX = 50.0
"""Largest blur length (pixels) :func:`motion_blur` accepts."""


def blur_flow(
    depth: NDArray[np.float32],
    k: NDArray[np.float64],
    c2w: NDArray[np.float64],
    c2w_next: NDArray[np.float64],
) -> NDArray[np.float64]:
    """``[H, W, 2]`` pixel motion (du, dv) from pose ``c2w`` to ``c2w_next``.

    Pixels with no depth (0) move as if at the median valid depth; with no valid depth at
    all the flow is zero.
    """
    z = depth.astype(np.float64)
    valid = z > 0
    if not valid.any():
        return np.zeros((*depth.shape, 2))
    z = np.where(valid, z, float(np.median(z[valid])))
    h, w = depth.shape
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    cam = np.stack([(u - k[0, 2]) / k[0, 0] * z, (v - k[1, 2]) / k[1, 1] * z, z], axis=-1)
    world = cam @ c2w[:3, :3].T + c2w[:3, 3]
    w2c = np.linalg.inv(c2w_next)
    moved = world @ w2c[:3, :3].T + w2c[:3, 3]
    depth_next = np.maximum(moved[..., 2], 1e-6)
    u2 = moved[..., 0] / depth_next * k[0, 0] + k[0, 2]
    v2 = moved[..., 1] / depth_next * k[1, 1] + k[1, 2]
    return np.stack([u2 - u, v2 - v], axis=-1)


def motion_blur(
    rgb: NDArray[np.uint8], flow: NDArray[np.float64], length_px: float
) -> NDArray[np.uint8]:
    """``rgb`` averaged along ``flow`` scaled to a median length of ``length_px`` pixels.

    Args:
        rgb: ``[H, W, 3]`` uint8 image.
        flow: ``[H, W, 2]`` pixel motion over the frame interval (:func:`blur_flow`).
        length_px: median blur length in pixels, in ``[0, MAX_BLUR_PX]``; 0 = no blur.

    Returns:
        ``[H, W, 3]`` uint8; ``rgb`` itself when there is nothing to blur.

    Raises:
        ValueError: ``length_px`` is out of range or the shapes disagree.
    """
    if not 0.0 <= length_px <= MAX_BLUR_PX:
        raise ValueError(f"blur length must be between 0 and {MAX_BLUR_PX} px, got {length_px}")
    if flow.shape != (*rgb.shape[:2], 2):
        raise ValueError(f"flow shape {flow.shape} does not match image {rgb.shape}")
    median = float(np.median(np.linalg.norm(flow, axis=-1)))
    if length_px == 0.0 or median <= 1e-9:
        return rgb
    step = flow * (length_px / median)
    samples = max(3, math.ceil(length_px) + 1)
    h, w = rgb.shape[:2]
    v, u = np.mgrid[0:h, 0:w].astype(np.float32)
    image = rgb.astype(np.float32)
    total = np.zeros_like(image)
    for t in np.linspace(-0.5, 0.5, samples):
        map_u = u + np.float32(t) * step[..., 0].astype(np.float32)
        map_v = v + np.float32(t) * step[..., 1].astype(np.float32)
        total += cv2.remap(image, map_u, map_v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return np.clip(np.rint(total / samples), 0, 255).astype(np.uint8)
