"""Reconstruction of an RGB-only COLMAP capture (issue 39 item 1): Gaussians from the sparse
points, photometric loss only, every depth-dependent step reported off."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from dcseg.depthless import DEPTH_OFF
from dcseg.io.captures import read_capture
from dcseg.io.captures.colmap_write import sample_sparse_points, write_colmap_rgb_only
from dcseg.reconstruct.config import PRESETS as RECONSTRUCT_PRESETS
from dcseg.reconstruct.config import ReconstructConfig
from dcseg.reconstruct.init import neighbour_log_scales
from dcseg.reconstruct.job import reconstruct_scene
from dcseg.reconstruct.rgbonly import (
    PHOTOMETRIC_ONLY,
    photometric_only,
    rgb_only_init,
    sparse_colour_changes,
    with_rendered_depth,
)
from dcseg.types import Capture
from tests.scenes.analytic import make_capture, surface_distance


@pytest.fixture(scope="module")
def rgb_only(tmp_path_factory: pytest.TempPathFactory) -> Capture:
    """The analytic box-on-a-floor scene, 8 views of 48x36, written as an RGB-only COLMAP
    model with 1500 sparse points (1 % depth noise) and read back."""
    scene = make_capture(frames=8, width=48, height=36)
    points = sample_sparse_points(scene, 1500, noise=0.01, seed=0)
    root = write_colmap_rgb_only(scene, points, tmp_path_factory.mktemp("colmap"))
    return read_capture(root)


def test_photometric_only_turns_every_depth_step_off() -> None:
    cfg = photometric_only(RECONSTRUCT_PRESETS["fast"])
    assert cfg.depth_weight == 0.0 and cfg.depth_filter_window == 1
    assert not cfg.drop_flying_pixels and not cfg.planar_depth
    assert cfg.thickness_weight == 0.0 and cfg.centre_weight == 0.0 and cfg.opacity_weight == 0.0
    assert set(PHOTOMETRIC_ONLY) <= set(vars(cfg))


def test_init_puts_gaussians_at_the_sparse_points(rgb_only: Capture) -> None:
    assert rgb_only.sparse is not None
    fast = RECONSTRUCT_PRESETS["fast"]
    cfg, extent, init = rgb_only_init(rgb_only, rgb_only.frames, fast, "cpu")
    assert cfg.depth_weight == 0.0 and len(init) == len(rgb_only.sparse) == 1500
    np.testing.assert_allclose(init.means.numpy(), rgb_only.sparse.xyz, atol=1e-5)
    colours = init.colors_dc().numpy()
    np.testing.assert_allclose(colours, rgb_only.sparse.rgb / 255.0, atol=1e-5)
    expected = neighbour_log_scales(rgb_only.sparse.xyz)
    np.testing.assert_allclose(init.log_scales[:, 0].numpy(), expected, atol=1e-5)
    assert 0.5 < extent < 20.0  # the cameras circle a 1 m box a few metres away
    assert float(np.median(surface_distance(rgb_only.sparse.xyz))) < 0.05


def test_init_keeps_at_most_max_init_points(rgb_only: Capture) -> None:
    cfg = replace(RECONSTRUCT_PRESETS["fast"], max_init_points=100)
    _, _, init = rgb_only_init(rgb_only, rgb_only.frames, cfg, "cpu")
    assert len(init) == 100


def test_init_needs_sparse_points(rgb_only: Capture) -> None:
    bare = replace(rgb_only, sparse=None)
    with pytest.raises(ValueError, match="needs sparse points"):
        rgb_only_init(bare, bare.frames, RECONSTRUCT_PRESETS["fast"], "cpu")


def test_reconstructs_with_photometric_loss_and_reports_depth_off(rgb_only: Capture) -> None:
    """Held-out PSNR within 1.5 dB of the same scene reconstructed with its depth (on 6
    training views of 48x36 neither generalises well: 14.5 vs 15.0 dB when written)."""
    cfg = replace(RECONSTRUCT_PRESETS["fast"], iterations=300, holdout=4, sh_degree=0)
    torch.manual_seed(0)
    gaussians, report, _ = reconstruct_scene(rgb_only, cfg, torch.device("cpu"))
    torch.manual_seed(0)
    _, with_depth, _ = reconstruct_scene(make_capture(8, 48, 36), cfg, torch.device("cpu"))
    assert report["test_frames"] == ["frame000", "frame004"]
    psnr = report["psnr"]
    assert psnr is not None and 12.0 < psnr < 60.0 and psnr > with_depth["psnr"] - 1.5
    assert report["final_loss"] < 0.5 * _first_loss(rgb_only, cfg)  # colour is fitted
    assert report["depth_mae"] is None and report["surface_depth_mae"] is None
    assert report["observed_share"] is None and report["psnr_observed"] is None  # needs depth
    assert report["depth_noise_at_1m"] is None
    assert all(v["depth_mae"] is None and v["depth_pixels"] == 0 for v in report["views"])
    depth = report["sensor"]["depth"]
    assert depth["present"] is False and depth["sparse_points"] == 1500
    assert depth["off"] == list(DEPTH_OFF) and depth["overrides"] == PHOTOMETRIC_ONLY
    assert "arbitrary" in depth["scale"] and report["sensor"]["poses"] is None
    exposure = report["sensor"]["exposure"]
    assert exposure["pair_changes"]["measured_by"] == "sparse points"
    assert exposure["detected"] is False and exposure["applied"] is False
    changed = {k: v["applied"] for k, v in report["config_changes"].items()}
    wanted = {k: v for k, v in PHOTOMETRIC_ONLY.items() if getattr(cfg, k) != v}
    assert changed == {**wanted, "pose_lr": 0.0}, changed
    assert report["initial_gaussians"] == 1500 and len(gaussians) > 0


def _first_loss(capture: Capture, cfg: ReconstructConfig) -> float:
    torch.manual_seed(0)
    _, report, _ = reconstruct_scene(capture, replace(cfg, iterations=1), torch.device("cpu"))
    return float(report["final_loss"])


def test_rendered_depth_stands_in_after_reconstruction(rgb_only: Capture) -> None:
    """The later stages see the surface depth rendered from the Gaussians: near the true
    depth where the scene is covered."""
    fast = RECONSTRUCT_PRESETS["fast"]
    _, _, init = rgb_only_init(rgb_only, rgb_only.frames, fast, "cpu")
    rendered = with_rendered_depth(rgb_only, init)
    assert rendered.depth_source == "rendered" and rendered.has_depth
    truth = make_capture(frames=8, width=48, height=36)
    for frame, true in zip(rendered.frames, truth.frames, strict=True):
        assert frame.files["depth"] == "rendered from the reconstruction"
        both = (frame.depth > 0) & (true.depth > 0)
        assert both.mean() > 0.5
        assert float(np.median(np.abs(frame.depth[both] - true.depth[both]))) < 0.1
    assert with_rendered_depth(truth, init) is truth  # a capture with depth keeps its own


def test_sparse_points_read_back_as_written(tmp_path: Path) -> None:
    scene = make_capture(frames=3, width=16, height=12)
    points = sample_sparse_points(scene, 30, seed=1)
    capture = read_capture(write_colmap_rgb_only(scene, points, tmp_path))
    assert capture.sparse is not None
    np.testing.assert_array_equal(capture.sparse.xyz, points.xyz)
    np.testing.assert_array_equal(capture.sparse.rgb, points.rgb)
    assert capture.sparse.track.tolist() == [2] * 30


def test_the_log_names_scores_that_were_not_measured() -> None:
    """An RGB-only run has no held-out depth and, without exposure fitting, no neighbours'
    exposure: the log says so instead of printing nan."""
    from dcseg.reconstruct.evaluate import Metrics
    from dcseg.reconstruct.stage import held_out_line

    nan = float("nan")
    line = held_out_line(Metrics((), 24.5, nan, nan, compensated_psnr=25.0))
    assert "nan" not in line and "no depth MAE (no held-out depth)" in line
    assert line.startswith("PSNR 24.50 dB, colour-compensated 25.00 dB")
    measured = held_out_line(Metrics((), 24.5, 0.012, 0.011, 25.0, 24.8))
    assert "neighbours' exposure 24.80 dB" in measured and "depth MAE 0.0120 m" in measured
    assert "training views saw" not in measured  # not measured: not named
    seen = held_out_line(Metrics((), 24.5, 0.012, 0.011, 25.0, 24.8, 26.1, 0.9))
    assert "over the 90.0 % of pixels training views saw 26.10 dB" in seen


def test_exposure_changes_are_measured_through_the_sparse_points(rgb_only: Capture) -> None:
    """Constant exposure measures 0; one frame 25 % darker shows as a 25-33 % change (up and
    back down) in every channel and is detected."""
    constant = sparse_colour_changes(rgb_only.frames, rgb_only.sparse)
    assert constant["pairs"] == len(rgb_only.frames) - 1 and constant["largest_change"] < 0.01
    frames = list(rgb_only.frames)
    darker = (frames[3].rgb.astype(np.float64) * 0.75).round().astype(np.uint8)
    frames[3] = replace(frames[3], rgb=darker)
    changed = sparse_colour_changes(frames, rgb_only.sparse)
    assert changed["largest_change"] == pytest.approx(1 / 0.75 - 1, abs=0.03)
    assert changed["largest_wb"] < 0.03
    assert sparse_colour_changes(frames, None)["pairs"] == 0
