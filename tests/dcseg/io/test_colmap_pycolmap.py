"""COLMAP models checked by an independent implementation, pycolmap (COLMAP's own C++ reader
and writer): models pycolmap writes read back with their poses, intrinsics and sparse points,
and the test fixtures of ``test_captures_colmap`` read by pycolmap as dcseg reads them."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pycolmap
import pytest

from dcseg.io.captures import read_capture
from dcseg.io.images import read_image, write_image
from dcseg.types import Capture, Intrinsics
from tests.dcseg.io.layouts import RgbdScene, make_scene, mm, scene_capture
from tests.dcseg.io.test_captures_colmap import remove_depth, write_colmap

POINTS = np.array([[0.5, 0.25, 2.0], [-1.0, 0.75, 3.5], [0.1, -0.2, 1.25]])
COLOURS = np.array([[200, 100, 50], [0, 255, 7], [12, 34, 56]], dtype=np.uint8)
ERRORS = [0.7, 1.5, 0.25]


def pycolmap_model(scene: RgbdScene, root: Path, binary: bool, depth: bool = True) -> Path:
    """Images (and depth) written by dcseg, the model by pycolmap: one PINHOLE camera, image
    ids not in name order, three points observed by 1, 2 and 3 images."""
    k = scene.k
    params = [k.fx, k.fy, k.cx + 0.5, k.cy + 0.5]  # COLMAP: pixel corner at (0, 0)
    model = pycolmap.Reconstruction()
    model.add_camera_with_trivial_rig(
        pycolmap.Camera(model="PINHOLE", width=k.width, height=k.height, params=params, camera_id=1)
    )
    for i in range(scene.n):
        write_image(root / "images" / f"frame_{i}.png", scene.rgb[i])
        if depth:
            write_image(root / "depth" / f"frame_{i}.png", mm(scene.depth[i]))
        w2c = np.linalg.inv(scene.c2w[i])
        pose = pycolmap.Rigid3d(pycolmap.Rotation3d(w2c[:3, :3]), w2c[:3, 3])
        points = [pycolmap.Point2D(np.array([1.0 + j, 2.0])) for j in range(3)]
        image = pycolmap.Image(name=f"frame_{i}.png", points2D=points, camera_id=1, image_id=20 - i)
        model.add_image_with_trivial_frame(image, pose)
    for p in range(len(POINTS)):
        track = pycolmap.Track()
        for i in range(p + 1):
            track.add_element(20 - i, p)
        point = model.add_point3D(POINTS[p], track, COLOURS[p])
        model.point3D(point).error = ERRORS[p]
    folder = root / "sparse" / "0"
    folder.mkdir(parents=True)
    (model.write_binary if binary else model.write_text)(str(folder))
    return root


@pytest.mark.parametrize("binary", [True, False])
def test_models_written_by_pycolmap_read_back(
    rgbd_scene: RgbdScene, tmp_path: Path, binary: bool
) -> None:
    capture = read_capture(pycolmap_model(rgbd_scene, tmp_path, binary))
    assert capture.layout == "colmap" and capture.depth_source == "sensor"
    assert capture.names == tuple(f"frame_{i}" for i in range(rgbd_scene.n))
    for frame, before in zip(capture.frames, scene_capture(rgbd_scene).frames, strict=True):
        np.testing.assert_array_equal(frame.rgb, before.rgb)
        np.testing.assert_allclose(frame.depth, before.depth, atol=1e-6)
        np.testing.assert_allclose(frame.c2w, before.c2w, atol=1e-9)
        assert frame.intrinsics == before.intrinsics


@pytest.mark.parametrize("binary", [True, False])
def test_rgb_only_model_written_by_pycolmap(
    rgbd_scene: RgbdScene, tmp_path: Path, binary: bool
) -> None:
    """Without depth/ the points pycolmap wrote are the sparse cloud: positions, colours,
    reprojection errors and track lengths."""
    capture = read_capture(pycolmap_model(rgbd_scene, tmp_path, binary, depth=False))
    assert capture.depth_source == "none"
    sparse = capture.sparse
    assert sparse is not None
    order = np.argsort(sparse.track)
    np.testing.assert_allclose(sparse.xyz[order], POINTS, atol=1e-12)
    np.testing.assert_array_equal(sparse.rgb[order], COLOURS)
    np.testing.assert_allclose(sparse.error[order], ERRORS, atol=1e-12)
    assert sparse.track[order].tolist() == [1, 2, 3]


def pycolmap_view(folder: Path) -> dict[str, tuple[np.ndarray, list[float]]]:
    """Per image name: the camera-to-world pose and PINHOLE parameters pycolmap reads."""
    model = pycolmap.Reconstruction(str(folder))
    out = {}
    for image in model.images.values():
        c2w = np.linalg.inv(np.vstack([image.cam_from_world().matrix(), [0, 0, 0, 1]]))
        out[image.name] = (c2w, list(model.camera(image.camera_id).params))
    return out


def check_same_as_pycolmap(capture: Capture, folder: Path) -> None:
    seen = pycolmap_view(folder)
    assert sorted(seen) == sorted(f"{name}.png" for name in capture.names)
    for frame in capture.frames:
        c2w, params = seen[f"{frame.name}.png"]
        np.testing.assert_allclose(frame.c2w, c2w, atol=1e-9)
        k = frame.intrinsics
        np.testing.assert_allclose([k.fx, k.fy, k.cx + 0.5, k.cy + 0.5], params, atol=1e-12)


@pytest.mark.parametrize("binary", [True, False])
def test_fixtures_read_by_pycolmap_as_by_dcseg(
    rgbd_scene: RgbdScene, tmp_path: Path, binary: bool
) -> None:
    """The fixture writer the other COLMAP tests use writes what COLMAP itself reads: the
    same poses, intrinsics and sparse point as dcseg's reader."""
    root = remove_depth(write_colmap(rgbd_scene, tmp_path, binary=binary))
    capture = read_capture(root)
    check_same_as_pycolmap(capture, root / "sparse" / "0")
    model = pycolmap.Reconstruction(str(root / "sparse" / "0"))
    point = model.point3D(12)
    sparse = capture.sparse
    assert sparse is not None
    np.testing.assert_array_equal(sparse.xyz[0], point.xyz)
    np.testing.assert_array_equal(sparse.rgb[0], point.color)
    assert sparse.error[0] == pytest.approx(point.error)
    assert sparse.track[0] == point.track.length()


def smooth_scene(seed: int = 0) -> RgbdScene:
    """Four 96x72 frames of smooth colour (interpolation differs little between resamplers)."""
    scene = make_scene(width=96, height=72, seed=seed)
    v, u = np.mgrid[0:72, 0:96].astype(np.float64)
    rgb = [
        np.stack(
            [
                128 + 100 * np.sin(u / (9.0 + i) + v / 13.0),
                128 + 100 * np.cos(v / (7.0 + i)),
                2.0 * u + v / 2.0,
            ],
            axis=-1,
        ).astype(np.uint8)
        for i in range(scene.n)
    ]
    return RgbdScene(rgb, scene.depth, scene.c2w, Intrinsics(80.0, 82.0, 47.0, 36.0, 96, 72))


def test_a_distorted_model_undistorted_as_pycolmap_undistorts_it(tmp_path: Path) -> None:
    """dcseg's own undistortion against COLMAP's undistorter (pycolmap): each pixel of dcseg's
    frame, looked up along its ray in COLMAP's undistorted image, has the same colour."""
    scene = smooth_scene()
    k = scene.k
    params = [k.fx, k.fy, k.cx + 0.5, k.cy + 0.5, -0.25, 0.06, 0.002, -0.001]
    cameras = {1: ("OPENCV", k.width, k.height, params)}
    root = remove_depth(write_colmap(scene, tmp_path / "raw", cameras=cameras))
    capture = read_capture(root)
    out = tmp_path / "colmap"
    pycolmap.undistort_images(str(out), str(root / "sparse" / "0"), str(root / "images"))
    undistorted = read_capture(out)  # what COLMAP's undistorter writes reads as it is
    assert all(f.undistortion is None for f in undistorted.frames)
    for theirs_frame, ours_frame in zip(undistorted.frames, capture.frames, strict=True):
        np.testing.assert_allclose(theirs_frame.c2w, ours_frame.c2w, atol=1e-6)
    model = pycolmap.Reconstruction(str(out / "sparse"))
    (camera,) = model.cameras.values()
    for frame, raw in zip(capture.frames, scene.rgb, strict=True):
        assert frame.undistortion is not None
        theirs = read_image(out / "images" / f"{frame.name}.png")
        ours, inside = looked_up(theirs, frame.intrinsics, camera)
        assert inside.mean() > 0.8  # COLMAP keeps a slightly narrower view
        diff = np.abs(ours.astype(np.int16) - frame.rgb.astype(np.int16))[inside]
        assert diff.mean() < 0.5 and diff.max() <= 2
        # the distorted image as it was, taken for a pinhole one, is far off
        as_pinhole, inside = looked_up(theirs, frame.undistortion.source, camera)
        assert np.abs(as_pinhole.astype(np.int16) - raw.astype(np.int16))[inside].mean() > 5


def looked_up(
    image: np.ndarray, k: Intrinsics, camera: pycolmap.Camera
) -> tuple[np.ndarray, np.ndarray]:
    """``image`` of COLMAP's PINHOLE ``camera`` sampled along the rays of ``k``'s pixels, and
    where those rays fall inside it."""
    fx, fy, cx, cy = camera.params  # COLMAP's pixel convention: centres at + 0.5
    v, u = np.mgrid[0 : k.height, 0 : k.width].astype(np.float64)
    x = ((u - k.cx) / k.fx * fx + cx - 0.5).astype(np.float32)
    y = ((v - k.cy) / k.fy * fy + cy - 0.5).astype(np.float32)
    inside = (x >= 1) & (x <= camera.width - 2) & (y >= 1) & (y <= camera.height - 2)
    return cv2.remap(image, x, y, cv2.INTER_LINEAR), inside
