"""Training views: a random window renders exactly the matching part of the whole view."""

from __future__ import annotations

import pytest
import torch

from dcseg.gaussians import Gaussians
from dcseg.reconstruct.config import FAST, ReconstructConfig
from dcseg.reconstruct.init import init_from_capture
from dcseg.reconstruct.views import make_view, random_crop
from dcseg.render import render
from tests.scenes.analytic import make_capture


def test_window_renders_the_crop_of_the_whole_view() -> None:
    """Exact up to rounding while the Gaussians are small next to the window (on a 40x30
    capture the projection's frustum clamp changes the footprint of big ones by up to 0.5 %)."""
    capture = make_capture(frames=4, width=160, height=120)
    gaussians: Gaussians = init_from_capture(capture, FAST)
    view = make_view(capture.frames[0])
    generator = torch.Generator().manual_seed(3)
    window = random_crop(view, 0.5, generator)
    cam = window.camera
    assert (cam.width, cam.height) == (80, 60)
    x0 = int(round(float(view.camera.K[0, 2] - cam.K[0, 2])))
    y0 = int(round(float(view.camera.K[1, 2] - cam.K[1, 2])))
    assert (x0, y0) != (0, 0)  # seed 3 gives an inner window
    whole = render(gaussians, gaussians.colors_dc(), view.camera)
    part = render(gaussians, gaussians.colors_dc(), cam)
    crop = (slice(y0, y0 + 60), slice(x0, x0 + 80))
    torch.testing.assert_close(part.values, whole.values[crop], atol=1e-5, rtol=1e-4)
    torch.testing.assert_close(part.depth, whole.depth[crop], atol=1e-4, rtol=1e-4)
    torch.testing.assert_close(window.rgb, view.rgb[crop])
    torch.testing.assert_close(window.depth, view.depth[crop])


def test_whole_fraction_returns_the_view_and_bad_fraction_is_rejected() -> None:
    view = make_view(make_capture(frames=1, width=16, height=12).frames[0])
    assert random_crop(view, 1.0, torch.Generator()) is view
    with pytest.raises(ValueError, match="full_res_crop"):
        ReconstructConfig(full_res_crop=0.0)
