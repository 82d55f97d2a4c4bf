"""Lens distortion removed: the resampling maps against COLMAP's own camera models (pycolmap,
an independent implementation), images, depth, masks and class maps resampled with them, and
the record ``run.json`` keeps."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pycolmap
import pytest
from numpy.typing import NDArray

from dcseg.errors import InputError
from dcseg.io.masks import decode_masks, masks_from_dense
from dcseg.lens import (
    _maps,
    from_records,
    lens_problem,
    nearest_pixels,
    records,
    redistort_labels,
    remap_linear,
    remap_nearest,
    undistort_agnostic,
    undistort_semantic,
    undistortion,
)
from dcseg.types import Intrinsics, Lens, SemanticMap, Undistortion

W, H = 64, 48
# COLMAP model, its parameters (COLMAP's pixel convention), the same lens in OpenCV's order
MODELS = [
    ("SIMPLE_RADIAL", [50.0, 32.0, 24.0, 0.1], Lens("opencv", (0.1, 0.0, 0.0, 0.0))),
    ("RADIAL", [50.0, 32.0, 24.0, -0.15, 0.03], Lens("opencv", (-0.15, 0.03, 0.0, 0.0))),
    (
        "OPENCV",
        [50.0, 52.0, 31.0, 25.0, -0.2, 0.05, 0.001, -0.002],
        Lens("opencv", (-0.2, 0.05, 0.001, -0.002)),
    ),
    (
        "FULL_OPENCV",
        [50.0, 52.0, 32.0, 24.0, -0.2, 0.05, 0.001, -0.002, 0.01, 0.02, 0.0, 0.01],
        Lens("opencv", (-0.2, 0.05, 0.001, -0.002, 0.01, 0.02, 0.0, 0.01)),
    ),
    (
        "OPENCV_FISHEYE",
        [50.0, 52.0, 32.0, 24.0, 0.05, -0.01, 0.002, 0.001],
        Lens("fisheye", (0.05, -0.01, 0.002, 0.001)),
    ),
]


def source_of(model: str, params: list[float]) -> Intrinsics:
    """dcseg's intrinsics of a COLMAP camera (principal point 0.5 px up-left)."""
    if model in ("SIMPLE_RADIAL", "RADIAL"):
        return Intrinsics(params[0], params[0], params[1] - 0.5, params[2] - 0.5, W, H)
    return Intrinsics(params[0], params[1], params[2] - 0.5, params[3] - 0.5, W, H)


def pixel_rays(k: Intrinsics) -> NDArray[np.float64]:
    """``[H * W, 3]`` rays (z = 1) through every pixel centre of ``k``."""
    v, u = np.mgrid[0 : k.height, 0 : k.width].astype(np.float64)
    rays = np.stack([(u - k.cx) / k.fx, (v - k.cy) / k.fy, np.ones_like(u)], axis=-1)
    return rays.reshape(-1, 3)


@pytest.mark.parametrize(("model", "params", "lens"), MODELS, ids=[m[0] for m in MODELS])
def test_maps_follow_colmaps_camera_models(model: str, params: list[float], lens: Lens) -> None:
    """Each undistorted pixel samples the distorted image where COLMAP projects its ray, and
    every pixel lies inside the distorted image (no blank border)."""
    u = undistortion(lens, source_of(model, params))
    x, y = _maps(u, W, H)
    rows, _ = nearest_pixels(u, W, H)
    camera = pycolmap.Camera(model=model, width=W, height=H, params=params)
    projected = camera.img_from_cam(pixel_rays(u.pinhole))
    assert projected is not None
    expected = np.asarray(projected) - 0.5  # to dcseg's pixel centres
    np.testing.assert_allclose(x.ravel(), expected[:, 0], atol=1e-3)
    np.testing.assert_allclose(y.ravel(), expected[:, 1], atol=1e-3)
    assert x.min() >= -0.5 and x.max() <= W - 0.5 and y.min() >= -0.5 and y.max() <= H - 0.5
    assert (u.pinhole.width, u.pinhole.height) == (W, H)
    np.testing.assert_array_equal(rows, np.clip(np.floor(y + 0.5), 0, H - 1))


def test_maps_at_a_working_size_scale_both_cameras() -> None:
    """At half the size the maps are the full-size ones in half-size pixels."""
    model, params, lens = MODELS[2]
    u = undistortion(lens, source_of(model, params))
    full_x, full_y = _maps(u, W, H)
    half_x, half_y = _maps(u, W // 2, H // 2)
    # pixel (i, j) at half size is the point (2i + 0.5, 2j + 0.5) at full size
    probe = full_x[1::2, 1::2], full_y[1::2, 1::2]
    np.testing.assert_allclose((half_x + 0.5) * 2 - 0.5, probe[0], atol=0.6)
    np.testing.assert_allclose((half_y + 0.5) * 2 - 0.5, probe[1], atol=0.6)


def linear_image(u: Undistortion) -> NDArray[np.uint8]:
    """A distorted image whose value is linear in the pixel position (bilinear is exact)."""
    v, x = np.mgrid[0:H, 0:W].astype(np.float64)
    return np.stack([x * 3, v * 4, x + v], axis=-1).astype(np.uint8)


def test_colour_is_resampled_bilinearly_depth_by_nearest() -> None:
    model, params, lens = MODELS[2]
    u = undistortion(lens, source_of(model, params))
    x, y = _maps(u, W, H)
    rows, cols = nearest_pixels(u, W, H)
    rgb = remap_linear(linear_image(u), u)
    assert rgb.dtype == np.uint8 and rgb.shape == (H, W, 3)
    np.testing.assert_allclose(rgb[..., 0], np.clip(x * 3, 0, None), atol=1.0)
    np.testing.assert_allclose(rgb[..., 1], np.clip(y * 4, 0, None), atol=1.0)
    depth = np.random.default_rng(0).uniform(0.5, 4.0, (H, W)).astype(np.float32)
    out = remap_nearest(depth, u)
    assert out.dtype == np.float32
    np.testing.assert_array_equal(out, depth[rows, cols])  # values taken, never mixed


def test_masks_and_class_maps_follow_their_frames() -> None:
    """A mask drawn on the distorted image lands where the frame's pixels do; frames without
    an undistortion keep their masks; a mask only in the cropped border is dropped."""
    model, params, lens = MODELS[2]
    u = undistortion(lens, source_of(model, params))
    rows, cols = nearest_pixels(u, W, H)
    dense = np.zeros((3, H, W), dtype=bool)
    dense[0, 10:30, 20:40] = True
    dense[1, :, :] = True
    dense[2, 0, 0] = True  # the corner the undistorted view does not reach
    masks = masks_from_dense("a", dense)
    out = undistort_agnostic({"a": masks, "b": masks}, {"a": u})
    assert out["b"] is masks
    got = decode_masks(out["a"])
    assert got.shape == (2, H, W)
    np.testing.assert_array_equal(got[0], dense[0][rows, cols])
    assert got[1].all()
    classes = np.full((H, W), -1, dtype=np.int32)
    classes[10:30, 20:40] = 3
    maps = undistort_semantic({"a": SemanticMap("a", classes)}, {"a": u})
    np.testing.assert_array_equal(maps["a"].classes, classes[rows, cols])


def test_records_round_trip_through_json() -> None:
    (m1, p1, l1), (m2, p2, l2) = MODELS[0], MODELS[4]
    u1, u2 = undistortion(l1, source_of(m1, p1)), undistortion(l2, source_of(m2, p2))
    frames = {"f0": u1, "f1": u2, "f2": u1}
    kept = json.loads(json.dumps(records(frames)))
    assert [entry["frames"] for entry in kept] == [["f0", "f2"], ["f1"]]
    assert from_records(kept) == frames
    assert records({}) == [] and from_records([]) == {}


@pytest.mark.parametrize(
    ("lens", "reason"),
    [
        (Lens("opencv", (0.1, 0.2, 0.3)), "opencv lens needs 4 or 5 or 8 coefficients, got 3"),
        (Lens("fisheye", (0.1,) * 5), "fisheye lens needs 4 coefficients, got 5"),
        (Lens("opencv", (float("nan"), 0, 0, 0)), "lens coefficients must be finite"),
        (Lens("fov", (0.9,)), "unknown lens model 'fov' (expected opencv or fisheye)"),  # type: ignore[arg-type]
    ],
)
def test_lens_problems(lens: Lens, reason: str) -> None:
    problem = lens_problem(lens)
    assert problem is not None and problem.startswith(reason)
    assert lens_problem(Lens("opencv", (0.1, 0.0, 0.0, 0.0, 0.01))) is None


@pytest.mark.parametrize(("model", "params", "lens"), MODELS, ids=[m[0] for m in MODELS])
def test_label_maps_go_back_onto_the_distorted_pixels(
    model: str, params: list[float], lens: Lens
) -> None:
    """Each distorted pixel takes the label of the undistorted pixel its ray (COLMAP's
    ``cam_from_img``) falls in; -1 where the undistorted view does not reach."""
    u = undistortion(lens, source_of(model, params))
    labels = np.arange(H * W, dtype=np.int64).reshape(H, W)
    back = redistort_labels(labels, u)
    camera = pycolmap.Camera(model=model, width=W, height=H, params=params)
    v, x = np.mgrid[0:H, 0:W].astype(np.float64)
    rays = camera.cam_from_img(np.stack([x.ravel(), v.ravel()], axis=1) + 0.5)
    assert rays is not None
    p = u.pinhole
    cols = np.floor(np.asarray(rays)[:, 0] * p.fx + p.cx + 0.5).reshape(H, W)
    rows = np.floor(np.asarray(rays)[:, 1] * p.fy + p.cy + 0.5).reshape(H, W)
    inside = (cols >= 0) & (cols < W) & (rows >= 0) & (rows < H)
    expected = np.where(inside, rows * W + cols, -1)
    assert (back == expected).mean() > 0.99  # ties at pixel borders may round either way
    assert abs(int((back < 0).sum()) - int((~inside).sum())) <= 3
    again = remap_nearest(back, u)  # and undistorted again: most pixels come home
    assert (again == labels).mean() > 0.8


def test_a_lens_opencv_cannot_use_is_a_problem_of_its_frames(tmp_path: Path) -> None:
    """A reader that hands over a malformed lens gets a problem naming where it was stated,
    not an OpenCV error."""
    from dcseg.config import CaptureOptions
    from dcseg.io.captures.common import Camera, FrameSpec, Listing, load_capture
    from dcseg.io.images import write_image

    write_image(tmp_path / "a.png", np.zeros((H, W, 3), np.uint8))
    write_image(tmp_path / "a_depth.png", np.ones((H, W), np.uint16))
    lens = Lens("opencv", (0.1, 0.2, 0.3), "calib.txt")
    camera = Camera(50.0, 50.0, 31.5, 23.5, None, "calib.txt", lens)
    spec = FrameSpec("a", tmp_path / "a.png", tmp_path / "a_depth.png", np.eye(4), camera, "p")
    with pytest.raises(InputError) as info:
        load_capture(Listing(specs=[spec]), tmp_path, "test", CaptureOptions())
    assert str(info.value.problems[0]) == (
        "calib.txt: opencv lens needs 4 or 5 or 8 coefficients, got 3"
    )
