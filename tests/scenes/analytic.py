"""A tiny analytic RGB-D scene for tests: a checkered floor and a box, ray-cast in numpy.

The floor is the plane z = 0 (|x|, |y| <= 1), the box spans [-0.25, 0.25]^2 x [0, 0.4]; cameras
orbit the origin at radius 1.6 and height 1.1 looking at (0, 0, 0.15). Depth is camera-space z.
"""

from __future__ import annotations

import math

import numpy as np

from dcseg.types import Capture, Frame, Intrinsics

BOX_LO = np.array([-0.25, -0.25, 0.0])
BOX_HI = np.array([0.25, 0.25, 0.4])
FLOOR_HALF = 1.0


def look_at(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    """A camera-to-world pose (OpenCV axes) at ``eye`` looking at ``target``, world +z up."""
    forward = (target - eye) / np.linalg.norm(target - eye)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, down, forward, eye
    return c2w


def _floor_colour(p: np.ndarray) -> np.ndarray:
    checks = (np.floor(p[:, 0] * 4) + np.floor(p[:, 1] * 4)) % 2
    base: np.ndarray = np.where(checks[:, None] > 0, [0.85, 0.8, 0.7], [0.25, 0.35, 0.55])
    return base


def _box_colour(p: np.ndarray, normal_axis: np.ndarray) -> np.ndarray:
    palette = np.array([[0.8, 0.2, 0.2], [0.2, 0.7, 0.3], [0.9, 0.8, 0.2]])
    stripes = 0.75 + 0.25 * (np.floor(p[:, 2] * 10) % 2)
    out: np.ndarray = palette[normal_axis] * stripes[:, None]
    return out


def _hit_box(origin: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (BOX_LO - origin) / dirs
        t2 = (BOX_HI - origin) / dirs
    t_near = np.minimum(t1, t2)
    t_far = np.maximum(t1, t2)
    enter = np.nanmax(t_near, axis=1)
    leave = np.nanmin(t_far, axis=1)
    hit = (enter <= leave) & (enter > 0)
    axis = np.nanargmax(t_near, axis=1)
    return np.where(hit, enter, np.inf), axis


def render_frame(c2w: np.ndarray, k: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
    """``(rgb uint8 [H, W, 3], depth float32 [H, W])`` of the scene from ``c2w``."""
    v, u = np.mgrid[0 : k.height, 0 : k.width]
    cam = np.stack(
        [(u - k.cx) / k.fx, (v - k.cy) / k.fy, np.ones_like(u, dtype=np.float64)], axis=-1
    ).reshape(-1, 3)
    dirs = cam @ c2w[:3, :3].T
    origin = c2w[:3, 3]
    with np.errstate(divide="ignore"):
        t_floor = np.where(dirs[:, 2] < 0, -origin[2] / dirs[:, 2], np.inf)
    floor_p = origin + t_floor[:, None] * dirs
    on_floor = np.all(np.abs(floor_p[:, :2]) <= FLOOR_HALF, axis=1)
    t_floor = np.where(on_floor, t_floor, np.inf)
    t_box, axis = _hit_box(origin, dirs)
    t = np.minimum(t_floor, t_box)
    points = origin + np.where(np.isfinite(t), t, 0.0)[:, None] * dirs
    colour = np.zeros_like(points)
    floor_sel = np.isfinite(t_floor) & (t_floor <= t_box)
    box_sel = np.isfinite(t_box) & (t_box < t_floor)
    colour[floor_sel] = _floor_colour(points[floor_sel])
    colour[box_sel] = _box_colour(points[box_sel], axis[box_sel])
    depth = np.where(np.isfinite(t), t, 0.0)  # direction has camera z = 1, so t is depth
    rgb = np.clip(colour * 255.0 + 0.5, 0, 255).astype(np.uint8)
    return rgb.reshape(k.height, k.width, 3), depth.reshape(k.height, k.width).astype(np.float32)


def make_capture(frames: int = 4, width: int = 32, height: int = 24) -> Capture:
    """A capture of ``frames`` views orbiting the scene at ``width`` x ``height``."""
    focal = 0.9 * width
    k = Intrinsics(focal, focal, width / 2 - 0.5, height / 2 - 0.5, width, height)
    out = []
    for i in range(frames):
        angle = 2 * math.pi * i / frames + 0.3
        eye = np.array([1.6 * math.cos(angle), 1.6 * math.sin(angle), 1.1])
        c2w = look_at(eye, np.array([0.0, 0.0, 0.15]))
        rgb, depth = render_frame(c2w, k)
        out.append(Frame(f"frame{i:03d}", rgb, depth, k, c2w))
    return Capture(tuple(out), layout="dcseg", root="analytic")


def surface_distance(points: np.ndarray) -> np.ndarray:
    """Distance of each point to the nearest scene surface (floor plane or box boundary)."""
    floor = np.abs(points[:, 2])
    inside = np.clip(points, BOX_LO, BOX_HI)
    outside_d = np.linalg.norm(points - inside, axis=1)
    inner = np.min(np.concatenate([points - BOX_LO, BOX_HI - points], axis=1), axis=1)
    box = np.where(outside_d > 0, outside_d, inner)
    out: np.ndarray = np.minimum(floor, box)
    return out
