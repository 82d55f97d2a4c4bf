"""A short fit on the analytic scene: the loss falls, metrics are finite, runs are seeded."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest
import torch

from dcseg.reconstruct import Reconstruction, fit_gaussians
from dcseg.reconstruct.config import FAST, ReconstructConfig
from dcseg.reconstruct.fit import means_lr
from tests.scenes.analytic import make_capture

TINY = replace(
    FAST,
    iterations=60,
    holdout=4,
    train_downscale=1,
    init_pixel_stride=1,
    densify_from=20,
    densify_every=20,
    densify_until=40,
    max_gaussians=2500,
)


@pytest.fixture(scope="module")
def result() -> Reconstruction:
    calls: list[tuple[int, int, float]] = []
    out = fit_gaussians(
        make_capture(4, 32, 24), TINY, on_progress=lambda i, n, loss: calls.append((i, n, loss))
    )
    assert [c[0] for c in calls] == list(range(1, 61))
    assert all(c[1] == 60 for c in calls)
    return out


def test_loss_decreases(result: Reconstruction) -> None:
    losses = result.losses
    assert len(losses) == 60
    assert sum(losses[-10:]) / 10 < 0.9 * sum(losses[:10]) / 10


def test_metrics_are_finite(result: Reconstruction) -> None:
    assert result.test_frames == ("frame000",)
    assert result.train_frames == ("frame001", "frame002", "frame003")
    (view,) = result.metrics.views
    assert math.isfinite(view.psnr) and view.psnr > 10.0
    assert math.isfinite(view.depth_mae) and view.depth_pixels > 0
    assert math.isfinite(view.surface_depth_mae) and view.surface_depth_mae < 0.5
    assert result.metrics.psnr == view.psnr
    assert result.metrics.surface_depth_mae == pytest.approx(view.surface_depth_mae)
    assert set(result.seconds) == {"registration", "init", "sensor", "train", "eval"}
    assert result.sensor["poses"]["refined"] is False and result.poses is None  # exact poses
    assert result.sensor["registration"]["applied_shift_px"] == [0, 0]  # registered
    assert result.sensor["registration"]["applied"]["scale"] == 1.0
    assert result.sensor["intrinsics"]["applied"] is None and result.cameras is None
    assert result.sensor["depth"]["flying_pixels"]["dropped"] is True
    blur = result.sensor["motion_blur"]
    assert blur["mode"] == "weight" and blur["frames_checked"] == 3
    g = result.gaussians
    assert len(g) > 0 and not g.means.requires_grad
    for tensor in (g.means, g.quats, g.log_scales, g.opacity_logits, g.sh):
        assert bool(torch.isfinite(tensor).all())


def test_sh_degree_one_and_seeded_runs_repeat() -> None:
    cfg = replace(TINY, iterations=12, sh_degree=1, sh_degree_interval=5, densify_until=0)
    capture = make_capture(4, 24, 18)
    a = fit_gaussians(capture, cfg)
    b = fit_gaussians(capture, cfg)
    assert a.gaussians.sh_degree == 1
    assert a.losses == b.losses
    assert torch.equal(a.gaussians.means, b.gaussians.means)
    assert float(a.gaussians.sh[:, 1:].abs().max()) > 0.0


def test_means_learning_rate_decays_log_linearly() -> None:
    cfg = ReconstructConfig(iterations=100, means_lr_init=1e-4, means_lr_final=1e-6)
    assert means_lr(0, cfg, 2.0) == pytest.approx(2e-4)
    assert means_lr(50, cfg, 2.0) == pytest.approx(2e-5)
    assert means_lr(100, cfg, 2.0) == pytest.approx(2e-6)


def test_config_validation() -> None:
    with pytest.raises(ValueError, match="sh_degree"):
        ReconstructConfig(sh_degree=4)
    with pytest.raises(ValueError, match="holdout"):
        ReconstructConfig(holdout=1)


def test_config_import_is_torch_free() -> None:
    import subprocess
    import sys

    code = "import sys, dcseg.reconstruct.config, dcseg.reconstruct; print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_coarse_to_fine_switches_resolution(monkeypatch: pytest.MonkeyPatch) -> None:
    import dcseg.reconstruct.fit as fit_module

    sizes: list[tuple[int, int, float]] = []
    original = fit_module.render_view

    def spy(gaussians, camera, degree, backend, *, planar=False):  # type: ignore[no-untyped-def]
        sizes.append((camera.width, camera.height, round(float(camera.K[0, 0]), 3)))
        return original(gaussians, camera, degree, backend, planar=planar)

    monkeypatch.setattr(fit_module, "render_view", spy)
    cfg = replace(TINY, iterations=6, train_downscale=2, full_res_from=4, densify_until=0)
    from dcseg.reconstruct.stage import fit_gaussians as fit

    capture = make_capture(4, 32, 24)
    fx = capture.frames[0].intrinsics.fx
    fit(capture, replace(cfg, full_res_crop=1.0))
    assert sizes == [(16, 12, fx / 2)] * 4 + [(32, 24, fx)] * 2
    sizes.clear()
    fit(capture, replace(cfg, full_res_crop=0.5))  # full-resolution windows: full focal length
    assert sizes == [(16, 12, fx / 2)] * 4 + [(16, 12, fx)] * 2
