"""Pose refinement: the correction's algebra, moving Gaussians equals moving the camera, a
misplaced view is pulled back to its true pose, and a fit returns every frame's refined pose."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from dcseg.reconstruct import fit_gaussians
from dcseg.reconstruct.align import align_pose, in_view
from dcseg.reconstruct.config import FAST, ReconstructConfig
from dcseg.reconstruct.fit import render_view
from dcseg.reconstruct.init import init_from_frames
from dcseg.reconstruct.poses import (
    corrected_c2w,
    corrected_camera,
    move_gaussians,
    pose_change,
    refinement_report,
    rotvec_matrix,
    rotvec_quat,
    with_poses,
)
from dcseg.reconstruct.views import View, make_view
from dcseg.render import Camera, render
from tests.scenes.analytic import make_capture

DELTA = torch.tensor([0.02, -0.015, 0.01, 0.03, -0.02, 0.01], dtype=torch.float64)


def test_rotation_vector_matches_scipy_and_is_smooth_at_zero() -> None:
    w = DELTA[:3]
    expected = Rotation.from_rotvec(w.numpy())
    np.testing.assert_allclose(rotvec_matrix(w).numpy(), expected.as_matrix(), atol=1e-12)
    x, y, z, s = expected.as_quat()
    np.testing.assert_allclose(rotvec_quat(w).numpy(), [s, x, y, z], atol=1e-12)
    zero = torch.zeros(3, dtype=torch.float64, requires_grad=True)
    torch.autograd.backward(rotvec_matrix(zero).sum())
    assert zero.grad is not None and bool(torch.isfinite(zero.grad).all())
    np.testing.assert_allclose(rotvec_matrix(zero.detach()).numpy(), np.eye(3), atol=1e-12)


def test_moving_the_gaussians_renders_the_refined_camera() -> None:
    capture = make_capture(2, 40, 30)
    cfg = replace(FAST, init_pixel_stride=1)
    gaussians = init_from_frames(capture.frames, cfg)
    camera = Camera.from_frame(capture.frames[0])
    colours = torch.rand(len(gaussians), 3, generator=torch.Generator().manual_seed(0))
    moved = render(move_gaussians(gaussians, DELTA.float(), camera), colours, camera)
    refined = render(gaussians, colours, corrected_camera(camera, DELTA.float()))
    torch.testing.assert_close(moved.values, refined.values, atol=2e-3, rtol=0)
    assert (render(gaussians, colours, camera).values - refined.values).abs().max() > 0.1


def test_corrected_pose_undoes_the_correction_and_pose_change_measures_it() -> None:
    c2w = make_capture(1).frames[0].c2w
    after = corrected_c2w(c2w, DELTA)
    degrees, metres = pose_change(c2w, after)
    assert degrees == pytest.approx(np.degrees(float(DELTA[:3].norm())), rel=1e-9)
    assert metres > 0.01
    assert pose_change(c2w, c2w) == pytest.approx((0.0, 0.0), abs=1e-6)
    np.testing.assert_allclose(corrected_c2w(c2w, torch.zeros(6)), c2w, atol=1e-12)


def test_pose_change_reads_a_slightly_non_orthonormal_pose_by_its_rotation() -> None:
    """7-Scenes poses (KinectFusion) are 1.6e-4 off orthonormal: the trace alone read 1.5 deg
    of change where the refinement turned the cameras 0.1 deg."""
    c2w = make_capture(1).frames[0].c2w
    stored = c2w.copy()
    stored[:3, :3] *= 0.99984
    assert pose_change(stored, c2w)[0] < 0.01
    turned = _misplaced(c2w, 0.1, 0.0)
    assert pose_change(stored, turned)[0] == pytest.approx(0.1, abs=0.01)
    assert pose_change(np.eye(4), np.diag([-1.0, -1.0, 1.0, 1.0]))[0] == pytest.approx(180.0)


def _misplaced(c2w: np.ndarray, degrees: float, metres: float) -> np.ndarray:
    out = c2w.copy()
    out[:3, :3] = Rotation.from_rotvec([0.0, np.radians(degrees), 0.0]).as_matrix() @ c2w[:3, :3]
    out[:3, 3] += [metres, -metres, 0.0]
    return out


def test_alignment_pulls_a_misplaced_view_back_to_its_true_pose() -> None:
    """A view rendered from the Gaussians at its true pose but given a pose 1 degree and
    2.8 cm off: aligning it to the frozen Gaussians removes most of the error, and the view
    given its true pose stays there."""
    capture = make_capture(6, 64, 48)
    cfg = replace(FAST, init_pixel_stride=1, pose_lr=2e-3, pose_align_steps=150, train_downscale=1)
    gaussians = init_from_frames(capture.frames[1:], cfg)
    frame = capture.frames[0]
    truth = make_view(frame, 1)
    with torch.no_grad():
        seen = render_view(gaussians, truth.camera, 0, None)
    target = View(frame.name, truth.camera, seen.values.clamp(0, 1), seen.depth)
    wrong_c2w = _misplaced(frame.c2w, 1.0, 0.02)
    wrong = replace(target, camera=Camera.from_frame(replace(frame, c2w=wrong_c2w)))
    before = pose_change(frame.c2w, wrong_c2w)
    after = pose_change(frame.c2w, corrected_c2w(wrong_c2w, align_pose(gaussians, wrong, cfg)))
    assert after[0] < before[0] / 5 and after[1] < before[1] / 5, (before, after)
    still = align_pose(gaussians, target, cfg)
    assert pose_change(frame.c2w, corrected_c2w(frame.c2w, still))[0] < 0.1
    off = replace(cfg, pose_lr=0.0)
    assert not bool(align_pose(gaussians, wrong, off).any())


def test_a_fit_with_refinement_returns_every_frame_pose() -> None:
    capture = make_capture(4, 32, 24)
    tiny = ReconstructConfig(
        iterations=30, holdout=4, train_downscale=1, init_pixel_stride=1, sh_degree=0,
        densify_from=10, densify_every=10, densify_until=20, max_gaussians=2500,
        pose_lr=1e-3, pose_from=0, pose_align_steps=5, pose_refinement="on",
    )  # fmt: skip
    result = fit_gaussians(capture, tiny)
    assert result.poses is not None and result.original_poses is not None
    assert set(result.poses) == {f.name for f in capture.frames}
    for frame in capture.frames:
        degrees, metres = pose_change(frame.c2w, result.poses[frame.name])
        assert 0.0 < degrees < 2.0 and metres < 0.05
    assert "align" in result.seconds
    report = refinement_report(result.original_poses, result.poses)
    assert set(report["poses"]) == set(result.poses)
    assert 0.0 < report["rotation_deg"]["median"] <= report["rotation_deg"]["max"]
    moved = with_poses(capture, result.poses)
    np.testing.assert_allclose(moved.frames[1].c2w, result.poses["frame001"])
    plain = fit_gaussians(capture, replace(tiny, pose_lr=0.0))
    assert plain.poses is None and plain.original_poses is None
    late = fit_gaussians(capture, replace(tiny, pose_from=tiny.iterations))
    assert late.poses is not None
    for name in late.train_frames:  # refinement never started: the capture's poses
        np.testing.assert_allclose(late.poses[name], capture.frames[int(name[-3:])].c2w)


def test_refinement_settings_are_validated() -> None:
    with pytest.raises(ValueError, match="pose_lr must be >= 0"):
        ReconstructConfig(pose_lr=-1e-3)
    with pytest.raises(ValueError, match="pose_from must be >= 0"):
        ReconstructConfig(pose_from=-1)
    with pytest.raises(ValueError, match="pose_align_lr must be > 0"):
        ReconstructConfig(pose_align_lr=0.0)
    with pytest.raises(ValueError, match="pose_align_steps must be >= 0"):
        ReconstructConfig(pose_align_steps=-1)


def test_alignment_sees_only_the_gaussians_in_and_near_the_view() -> None:
    capture = make_capture(4, 40, 30)
    gaussians = init_from_frames(capture.frames, replace(FAST, init_pixel_stride=1))
    camera = Camera.from_frame(capture.frames[0])
    near = in_view(gaussians, camera)
    assert 0 < int(near.sum()) < len(gaussians)
    wide = in_view(gaussians, camera, margin=10.0)
    assert bool((wide | ~near).all()) and int(wide.sum()) > int(near.sum())
    # what is culled barely reaches the view (a large splat's tail at the border)
    colours = torch.rand(len(gaussians), 3, generator=torch.Generator().manual_seed(1))
    full = render(gaussians, colours, camera).values
    kept = render(gaussians.subset(near), colours[near], camera).values
    assert float((full - kept).abs().max()) < 0.02 and float((full - kept).abs().mean()) < 1e-3
