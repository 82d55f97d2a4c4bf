"""Render views with pybullet's CPU TinyRenderer and turn them into dcseg-convention arrays."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from dcseg.synth.cameras import CameraModel, view_matrix
from dcseg.synth.catalogue import VOCABULARY
from dcseg.synth.scene import SceneInstance


@dataclass(frozen=True)
class Lighting:
    """A fixed directional light (the same for every view, so colours are view-consistent)."""

    direction: tuple[float, float, float]
    ambient: float = 0.6
    diffuse: float = 0.5
    specular: float = 0.1


@dataclass(frozen=True)
class RenderedView:
    """One rendered view.

    Attributes:
        rgb: ``[H, W, 3]`` uint8 RGB.
        depth: ``[H, W]`` float32 metric z-depth, 0 where nothing was hit.
        body: ``[H, W]`` int32 pybullet body id per pixel, -1 where nothing was hit.
    """

    rgb: NDArray[np.uint8]
    depth: NDArray[np.float32]
    body: NDArray[np.int32]


def render_view(
    client: int,
    camera: CameraModel,
    c2w: NDArray[np.float64],
    light: Lighting,
    supersample: int = 1,
) -> RenderedView:
    """Render RGB, metric depth and body ids of one camera-to-world pose (OpenCV axes).

    With ``supersample = s > 1`` the colour is rendered at ``s`` x the resolution and
    area-averaged (anti-aliased, like a real sensor integrating over each pixel), while depth and
    body ids stay point samples at the pixel centres of ``camera``.
    """
    rgb, buffer, seg = _camera_image(client, camera, c2w, light)
    if supersample > 1:
        fine = _camera_image(client, camera.supersampled(supersample), c2w, light)[0]
        size = (camera.width, camera.height)
        rgb = np.asarray(cv2.resize(fine, size, interpolation=cv2.INTER_AREA), dtype=np.uint8)
    raw = np.asarray(seg, dtype=np.int64).reshape(camera.height, camera.width)
    body = np.where(raw >= 0, raw & ((1 << 24) - 1), -1).astype(np.int32)
    depth = camera.linear_depth(np.asarray(buffer, dtype=np.float64))
    depth[body < 0] = 0.0
    return RenderedView(rgb=rgb, depth=depth, body=body)


def _camera_image(
    client: int, camera: CameraModel, c2w: NDArray[np.float64], light: Lighting
) -> tuple[NDArray[np.uint8], NDArray[np.float64], Any]:
    """pybullet's TinyRenderer output: ``[H, W, 3]`` RGB, ``[H, W]`` window depth, segmentation."""
    import pybullet as p

    w, h = camera.width, camera.height
    _, _, rgba, buffer, seg = p.getCameraImage(
        w,
        h,
        viewMatrix=view_matrix(c2w),
        projectionMatrix=camera.projection_matrix(),
        renderer=p.ER_TINY_RENDERER,
        shadow=1,
        lightDirection=list(light.direction),
        lightAmbientCoeff=light.ambient,
        lightDiffuseCoeff=light.diffuse,
        lightSpecularCoeff=light.specular,
        physicsClientId=client,
    )
    rgb = np.ascontiguousarray(np.asarray(rgba, dtype=np.uint8).reshape(h, w, 4)[..., :3])
    return rgb, np.asarray(buffer, dtype=np.float64).reshape(h, w), seg


def instance_lookup(instances: Sequence[SceneInstance]) -> tuple[NDArray[np.int32], ...]:
    """Tables mapping ``body + 1`` to instance id and to class index (-1 for none)."""
    size = max(i.body for i in instances) + 2
    to_instance = np.full(size, -1, dtype=np.int32)
    to_class = np.full(size, -1, dtype=np.int32)
    for inst in instances:
        to_instance[inst.body + 1] = inst.id
        to_class[inst.body + 1] = VOCABULARY.index(inst.class_name)
    return to_instance, to_class


def ground_truth_maps(
    body: NDArray[np.int32], lookup: tuple[NDArray[np.int32], ...]
) -> tuple[NDArray[np.int32], NDArray[np.int32]]:
    """Per-pixel instance ids and class indices (``-1`` = none) of a body-id image."""
    to_instance, to_class = lookup
    index = np.clip(body + 1, 0, len(to_instance) - 1)
    return to_instance[index], to_class[index]


def backproject(
    depth: NDArray[np.float32], k: NDArray[np.float64], c2w: NDArray[np.float64]
) -> NDArray[np.float64]:
    """World coordinates ``[H, W, 3]`` of every pixel (meaningless where depth is 0)."""
    h, w = depth.shape
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    z = depth.astype(np.float64)
    x = (u - k[0, 2]) / k[0, 0] * z
    y = (v - k[1, 2]) / k[1, 1] * z
    cam = np.stack([x, y, z], axis=-1)
    out: NDArray[np.float64] = cam @ c2w[:3, :3].T + c2w[:3, 3]
    return out
