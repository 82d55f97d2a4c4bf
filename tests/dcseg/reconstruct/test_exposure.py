"""Per-view exposure: detection at corresponding pixels, the auto rule, a known gain recovered
by the fit, the reference folded into the exported colours, and the compensated PSNR."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import torch

from dcseg.gaussians import SH_C0, Gaussians
from dcseg.reconstruct import fit_gaussians
from dcseg.reconstruct.config import FAST
from dcseg.reconstruct.exposure import (
    colour_changes,
    compensated_psnr,
    decide,
    interpolated,
    pair_change,
    referenced,
)
from dcseg.reconstruct.losses import psnr
from dcseg.types import Capture
from tests.scenes.analytic import make_capture

TINY = replace(
    FAST,
    iterations=400,
    holdout=0,
    train_downscale=1,
    full_res_from=None,
    init_pixel_stride=1,
    densify_from=50,
    densify_every=50,
    densify_until=300,
    max_gaussians=4000,
)


def with_gains(capture: Capture, gains: list[float]) -> Capture:
    """``capture`` with frame ``i``'s colour times ``gains[i]`` (saturating at 255)."""
    frames = tuple(
        replace(f, rgb=np.clip(np.rint(f.rgb * g), 0, 255).astype(np.uint8))
        for f, g in zip(capture.frames, gains, strict=True)
    )
    return replace(capture, frames=frames)


def test_a_gain_between_frames_is_measured_at_corresponding_pixels() -> None:
    capture = make_capture(8, 64, 48)
    a, b = capture.frames[0], capture.frames[1]
    assert pair_change(a, b) == pytest.approx(np.zeros(3), abs=0.01)  # other view, same colour
    brighter = with_gains(capture, [1.0, 1.1] + [1.0] * 6).frames[1]
    assert pair_change(a, brighter) == pytest.approx(np.full(3, math.log(1.1)), abs=0.01)


def test_auto_turns_on_for_varying_exposure_and_stays_off_for_constant() -> None:
    capture = make_capture(8, 64, 48)
    constant = colour_changes(capture.frames)
    assert constant["pairs"] == 7 and constant["largest_change"] < 0.01
    varying = colour_changes(with_gains(capture, [1.0, 1.2] * 4).frames)
    assert varying["largest_change"] == pytest.approx(0.2, abs=0.02)
    assert decide("auto", varying) and not decide("auto", constant)
    assert decide("on", constant) and not decide("off", varying)
    assert not decide("auto", {"pairs": 0, "largest_change": None})


def test_the_reference_folds_into_the_colours_without_changing_any_view() -> None:
    gen = torch.Generator().manual_seed(0)
    n = 50
    sh = torch.randn(n, 1, 3, generator=gen) * 0.3
    g = Gaussians(torch.randn(n, 3), torch.randn(n, 4), torch.zeros(n, 3), torch.zeros(n), sh)
    params = [torch.randn(6, generator=gen) * 0.1 for _ in range(3)]
    folded, relative = referenced(g, params)
    before = 0.5 + SH_C0 * g.sh[:, 0]
    after = 0.5 + SH_C0 * folded.sh[:, 0]
    for p, rel in zip(params, relative, strict=True):
        expected = before * torch.exp(p[:3]) + p[3:]
        assert torch.allclose(after * torch.exp(rel[:3]) + rel[3:], expected, atol=1e-5)
    assert torch.allclose(relative[:, :3].mean(dim=0), torch.zeros(3), atol=1e-6)


def test_compensated_psnr_forgives_an_affine_colour_change_only() -> None:
    gen = torch.Generator().manual_seed(1)
    image = torch.rand(24, 32, 3, generator=gen) * 0.8
    shifted = image * torch.tensor([1.2, 1.0, 0.9]) + 0.05
    assert psnr(image, shifted) < 25.0
    assert compensated_psnr(image, shifted) > 60.0
    noise = torch.rand(24, 32, 3, generator=gen)
    assert compensated_psnr(noise, shifted) < 15.0  # no affine map turns noise into the image


def test_the_fit_recovers_a_known_gain_and_exports_the_reference_exposure() -> None:
    gains = [1.0, 0.75] * 4  # darker: no channel saturates
    capture = with_gains(make_capture(8, 48, 36), gains)
    out = fit_gaussians(capture, TINY)
    report = out.sensor["exposure"]
    assert report["detected"] and report["applied"] and report["mode"] == "auto"
    views = report["fitted"]["views"]
    assert set(views) == {f.name for f in capture.frames}
    fitted = np.array([views[f.name]["gain"] for f in capture.frames])
    ratio = fitted[1::2].mean(axis=0) / fitted[0::2].mean(axis=0)
    assert ratio == pytest.approx(np.full(3, 0.75), rel=0.05)
    geometric = np.exp(np.log(fitted).mean(axis=0))
    assert geometric == pytest.approx(np.ones(3), abs=1e-3)  # relative to the reference
    off = fit_gaussians(capture, replace(TINY, exposure="off", holdout=4))
    assert off.sensor["exposure"]["applied"] is False
    assert off.sensor["exposure"]["detected"] is True
    assert off.sensor["exposure"]["fitted"] is None


def test_held_out_views_report_raw_and_compensated_psnr() -> None:
    capture = with_gains(make_capture(8, 48, 36), [1.0, 0.75] * 4)
    out = fit_gaussians(capture, replace(TINY, iterations=100, holdout=4))
    metrics = out.metrics
    assert math.isfinite(metrics.psnr) and math.isfinite(metrics.compensated_psnr)
    assert metrics.compensated_psnr >= metrics.psnr - 0.5
    per_view = [v.compensated_psnr for v in metrics.views]
    assert len(per_view) == 2 and np.mean(per_view) == pytest.approx(metrics.compensated_psnr)
    assert math.isfinite(metrics.neighbour_psnr)  # exposure fitted: predicted for held-out views
    off = fit_gaussians(capture, replace(TINY, iterations=20, holdout=4, exposure="off"))
    assert math.isnan(off.metrics.neighbour_psnr) and math.isfinite(off.metrics.psnr)


def test_a_held_out_frame_takes_the_exposure_of_the_trained_frames_around_it() -> None:
    transforms = torch.tensor([[0.1] * 3 + [0.0] * 3, [0.3] * 3 + [0.02] * 3])
    out = interpolated([1, 5], transforms, [0, 2, 6])
    assert out[0, 0] == pytest.approx(0.1)  # before the first trained frame: its transform
    assert out[1, 0] == pytest.approx(0.15) and out[1, 3] == pytest.approx(0.005)
    assert out[2, 0] == pytest.approx(0.3)


def test_auto_leaves_a_constant_exposure_alone() -> None:
    out = fit_gaussians(make_capture(8, 48, 36), replace(TINY, iterations=20, holdout=4))
    report = out.sensor["exposure"]
    assert report["pair_changes"]["pairs"] == 5  # the training frames 1-3, 5-7
    assert report["detected"] is False and report["applied"] is False
    assert report["fitted"] is None and report["threshold"] == pytest.approx(0.03)
