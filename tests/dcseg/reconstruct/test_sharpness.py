"""Motion-blurred frames: scored against their neighbours, down-weighted or skipped, reported."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from numpy.typing import NDArray

from dcseg.reconstruct.config import ReconstructConfig
from dcseg.reconstruct.fit import step_loss
from dcseg.reconstruct.sharpness import (
    BLURRED,
    blur_decision,
    blur_scores,
    covered,
    sharpness,
)
from dcseg.reconstruct.views import View
from dcseg.render import Camera, RenderOutput
from dcseg.types import Frame, Intrinsics

K = Intrinsics(fx=200.0, fy=200.0, cx=159.5, cy=119.5, width=320, height=240)


def texture(seed: int = 0) -> NDArray[np.float64]:
    """A 240x960 grey texture with detail at every scale (smoothed noise plus edges)."""
    rng = np.random.default_rng(seed)
    fine = rng.random((240, 960))
    coarse = np.kron(rng.random((30, 120)), np.ones((8, 8)))
    return 0.5 * fine + 0.5 * coarse


def smear(image: NDArray[np.float64], length: int) -> NDArray[np.float64]:
    """``image`` averaged over ``length`` horizontal shifts (a camera panning while exposed)."""
    out: NDArray[np.float64] = np.mean([np.roll(image, s, axis=1) for s in range(length)], axis=0)
    return out


def frame(
    grey: NDArray[np.float64], name: str = "f", c2w: NDArray[np.float64] | None = None
) -> Frame:
    rgb = np.repeat((np.clip(grey, 0, 1) * 255).astype(np.uint8)[..., None], 3, axis=-1)
    depth = np.full((240, 320), 2.0, np.float32)
    return Frame(name, rgb, depth, K, np.eye(4) if c2w is None else c2w)


def pan(blurred: set[int], count: int = 9, length: int = 12) -> list[Frame]:
    """``count`` views panning over the texture (content changes from view to view, and the
    texture's detail with it: the right half is smoother), ``blurred`` ones smeared."""
    tex = texture()
    tex[:, 480:] = smear(tex[:, 480:], 3)
    views = []
    for i in range(count):
        crop = tex[:, i * 60 : i * 60 + 320]
        views.append(frame(smear(crop, length) if i in blurred else crop, f"frame{i:03d}"))
    return views


def test_a_blurred_frame_scores_below_its_sharp_neighbours() -> None:
    frames = pan({4})
    values = [sharpness(f.rgb) for f in frames]
    assert values[4] < 0.5 * min(values[3], values[5])
    scores = blur_scores(values)
    assert scores[4] < BLURRED
    assert np.delete(scores, 4).min() > BLURRED  # the smoother half is not taken for blur


def test_a_run_of_blurred_frames_at_the_start_is_found() -> None:
    """The first three frames blurred: their own low values do not become their reference."""
    scores = blur_decision(pan({0, 1, 2}), "weight").scores
    assert (scores[:3] < BLURRED).all()
    assert (scores[3:] > BLURRED).all()


def test_weight_scales_blurred_colour_and_leaves_sharp_frames_alone() -> None:
    frames = pan({2, 6})
    weighted = blur_decision(frames, "weight")
    assert list(np.flatnonzero(weighted.blurred)) == [2, 6]
    np.testing.assert_allclose(weighted.weights[[2, 6]], weighted.scores[[2, 6]])
    assert (weighted.weights[[2, 6]] < BLURRED).all()
    assert (np.delete(weighted.weights, [2, 6]) == 1.0).all()
    off = blur_decision(frames, "off")
    assert off.blurred.sum() == 2 and (off.weights == 1.0).all()  # detected, not applied
    sharp = blur_decision(pan(set()), "weight")
    assert not sharp.blurred.any() and (sharp.weights == 1.0).all()
    with pytest.raises(ValueError, match="blurred_frames"):
        blur_decision(frames, "drop")


def turned(degrees: float) -> NDArray[np.float64]:
    """A camera at the origin turned about its y axis."""
    a = np.radians(degrees)
    c2w = np.eye(4)
    c2w[:3, :3] = [[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]]
    return c2w


def test_skip_drops_colour_only_where_sharp_neighbours_see_the_same() -> None:
    frames = pan({2, 6})
    # frame 6 looks the other way than every other frame: nobody else sees its wall
    frames[6] = frame(np.asarray(frames[6].rgb[..., 0], float) / 255, "frame006", turned(180))
    assert covered(frames, 2, np.isin(np.arange(9), [2, 6])) == 1.0
    assert covered(frames, 6, np.isin(np.arange(9), [2, 6])) == 0.0
    skip = blur_decision(frames, "skip")
    assert skip.weights[2] == 0.0  # skipped: its neighbours cover it
    assert skip.weights[6] == pytest.approx(skip.scores[6])  # kept, weighted: nobody covers it
    assert skip.weights[6] > 0


def test_the_report_lists_blurred_frames_and_the_score_distribution() -> None:
    frames = pan({2, 6})
    report = blur_decision(frames, "skip").report([f.name for f in frames])
    assert report["mode"] == "skip" and report["threshold"] == BLURRED
    assert report["frames_checked"] == 9 and report["blurred"] == 2 and report["skipped"] == 2
    assert [f["name"] for f in report["frames"]] == ["frame002", "frame006"]
    assert all(f["colour_weight"] == 0.0 and f["coverage"] == 1.0 for f in report["frames"])
    q = report["score_quantiles"]
    assert q["min"] < BLURRED < q["median"] and q["min"] <= q["p5"] <= q["p25"] <= q["median"]
    assert report["seconds"] >= 0.0


def test_the_colour_weight_scales_the_colour_loss_only() -> None:
    cam = Camera(torch.eye(4), torch.eye(3), 4, 4)
    view = View("v", cam, torch.zeros(4, 4, 3), torch.ones(4, 4))
    out = RenderOutput(torch.full((4, 4, 3), 0.5), torch.ones(4, 4), torch.full((4, 4), 1.5))
    cfg = ReconstructConfig(ssim_lambda=0.0, depth_weight=0.5)
    full = float(step_loss(out, view, cfg))
    assert full == pytest.approx(0.5 + 0.5 * 0.5)
    assert float(step_loss(out, view, cfg, 0.2)) == pytest.approx(0.2 * 0.5 + 0.25)
    assert float(step_loss(out, view, cfg, 0.0)) == pytest.approx(0.25)  # depth stays


def test_config_refuses_an_unknown_mode() -> None:
    assert ReconstructConfig().blurred_frames == "weight"
    with pytest.raises(ValueError, match="blurred_frames"):
        ReconstructConfig(blurred_frames="drop")
