"""Held-out pixels the training frames observed: seen where a training frame looks, unseen where
none does, and the PSNR over the seen ones reported beside the raw PSNR."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import torch

from dcseg.reconstruct.evaluate import evaluate
from dcseg.reconstruct.observed import observed
from dcseg.reconstruct.views import make_view
from dcseg.types import Frame
from tests.scenes.analytic import make_capture


def _turned_around(frame: Frame) -> Frame:
    """``frame`` looking the other way (half a turn about its y axis)."""
    c2w = frame.c2w.copy()
    c2w[:3, :3] = c2w[:3, :3] @ np.diag([-1.0, 1.0, -1.0])
    return replace(frame, c2w=c2w)


def test_a_frame_sees_its_own_depth_and_one_looking_away_sees_none() -> None:
    frames = make_capture(4, 32, 24).frames
    test = frames[0]
    has_depth = test.depth > 0
    assert has_depth.any() and not has_depth.all()  # the analytic scene has empty sky
    assert (observed(test, [test], grid=1) == has_depth).all()  # without depth: not checked
    assert not observed(test, [_turned_around(test)], grid=1).any()
    neighbours = observed(test, frames[1:], grid=1)
    assert 0.0 < neighbours[has_depth].mean() <= 1.0
    coarse = observed(test, frames[1:])  # every 4th pixel checked, the rest take its answer
    assert coarse.shape == neighbours.shape and (coarse == neighbours).mean() > 0.8


def test_the_seen_region_is_the_part_a_training_frame_looks_at() -> None:
    """A training frame turned sideways sees one side of the held-out view, not the other."""
    frames = make_capture(4, 32, 24).frames
    test = frames[0]
    turn = np.radians(25.0)
    spin = np.array([[np.cos(turn), 0, np.sin(turn)], [0, 1, 0], [-np.sin(turn), 0, np.cos(turn)]])
    c2w = test.c2w.copy()
    c2w[:3, :3] = c2w[:3, :3] @ spin
    mask = observed(test, [replace(test, c2w=c2w)])
    depth = test.depth > 0
    left, right = mask[:, :12][depth[:, :12]].mean(), mask[:, 20:][depth[:, 20:]].mean()
    assert abs(left - right) > 0.5, (left, right)


def test_evaluate_reports_the_psnr_over_the_observed_pixels() -> None:
    frames = make_capture(4, 32, 24).frames
    views = [make_view(f, 1) for f in frames[:2]]
    from tests.dcseg.reconstruct.test_surface import SMALL, _fitted_from_displaced

    gaussians = _fitted_from_displaced(SMALL)
    plain = evaluate(gaussians, views)
    assert math.isnan(plain.observed_psnr) and math.isnan(plain.observed_share)
    everything = [torch.ones(24, 32, dtype=torch.bool) for _ in views]
    full = evaluate(gaussians, views, observed=everything)
    assert full.observed_share == 1.0 and full.observed_psnr == plain.psnr
    half = [torch.zeros(24, 32, dtype=torch.bool) for _ in views]
    for mask in half:
        mask[:, :16] = True
    some = evaluate(gaussians, views, observed=half)
    assert some.observed_share == 0.5 and some.observed_psnr != plain.psnr
    none = evaluate(gaussians, views, observed=[torch.zeros(24, 32, dtype=torch.bool)] * 2)
    assert none.observed_share == 0.0 and math.isnan(none.observed_psnr)
