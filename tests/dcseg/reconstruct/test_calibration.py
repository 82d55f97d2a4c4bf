"""Wrong intrinsics found from how the frames' depth agrees across views; exact ones kept."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from dcseg.reconstruct import fit_gaussians
from dcseg.reconstruct.calibration import (
    MIN_GAIN,
    MIN_PAIRS,
    Correction,
    corrected,
    decide,
    estimate,
    pairs,
)
from dcseg.reconstruct.config import ReconstructConfig
from dcseg.types import Capture, Frame, Intrinsics, Lens, Undistortion

pytest.importorskip("pybullet", reason="the synthetic scene generator needs pybullet")


@pytest.fixture(scope="module")
def capture() -> Capture:
    from dcseg.synth import SynthConfig, generate_scene

    return generate_scene(SynthConfig(seed=1, frames=16, width=160, height=120)).capture


def wrong(frames: tuple[Frame, ...], scale: float, dx: float, dy: float) -> tuple[Frame, ...]:
    """``frames`` with the intrinsics a user would give wrongly: focal x ``scale``, principal
    point moved by ``(dx, dy)``."""
    return corrected(frames, Correction(scale, (dx, dy), (frames[0].width, frames[0].height)))


def test_a_wrong_focal_length_and_principal_point_are_recovered(capture: Capture) -> None:
    given = wrong(capture.frames, 1.1, 4.0, -3.0)  # e.g. a Kinect's nominal 585 for its 530
    measured = estimate(given)
    fix = decide("auto", measured)
    assert fix is not None and measured["gain"] > 2 * MIN_GAIN, measured
    truth, found = capture.frames[0].intrinsics, fix.apply(given[0].intrinsics)
    assert found.fx == pytest.approx(truth.fx, rel=0.01) and found.fy / found.fx == 1.0
    assert abs(found.cx - truth.cx) <= 1.0 and abs(found.cy - truth.cy) <= 1.0, measured


def test_exact_intrinsics_are_kept(capture: Capture) -> None:
    measured = estimate(capture.frames)
    assert measured["gain"] < MIN_GAIN / 3, measured
    assert decide("auto", measured) is None
    assert decide("off", {**measured, "gain": 0.9}) is None
    assert decide("auto", {**measured, "gain": 0.9, "pairs": MIN_PAIRS - 1}) is None


def test_pairs_need_views_a_few_degrees_apart(capture: Capture) -> None:
    chosen = pairs(capture.frames)
    assert 0 < len(chosen) <= 12 and len(set(chosen)) == len(chosen)
    same = tuple(replace(f, c2w=capture.frames[0].c2w) for f in capture.frames)
    assert pairs(same) == []
    assert estimate(same) == {"pairs": 0, "correction": None, "gain": None}


def test_a_correction_scales_with_the_image_and_its_record_is_checked() -> None:
    fix = Correction(0.9, (4.0, -2.0), (640, 480))
    half = Intrinsics(fx=300.0, fy=300.0, cx=160.0, cy=120.0, width=320, height=240)
    assert fix.apply(half) == replace(half, fx=270.0, fy=270.0, cx=162.0, cy=119.0)
    assert Correction.of_record(fix.record()) == fix
    bad = (("focal_scale", 0), ("focal_scale", True), ("principal_shift_px", [1]),
           ("principal_shift_px", [True, 0]), ("at_size", [0, 4]))  # fmt: skip
    for field, value in bad:
        with pytest.raises(ValueError, match=f'"{field}"'):
            Correction.of_record({**fix.record(), field: value})
    with pytest.raises(ValueError, match="must be an object"):
        Correction.of_record([0.9])  # type: ignore[arg-type]


def test_a_correction_with_its_given_intrinsics_is_absolute() -> None:
    """Recorded with the intrinsics it was measured from, a correction gives the same cameras
    whatever the capture states later (scaled to its size), and says when it replaces them."""
    fix = Correction(0.9, (4.0, -2.0), (640, 480), given=(600.0, 600.0, 319.5, 239.5))
    stated = Intrinsics(fx=600.0, fy=600.0, cx=319.5, cy=239.5, width=640, height=480)
    fitted = Intrinsics(fx=540.0, fy=540.0, cx=323.5, cy=237.5, width=640, height=480)
    assert fix.apply(stated) == fitted and not fix.replaces(stated)
    other = replace(stated, fx=540.0, fy=540.0)  # a user giving the corrected ones later
    assert fix.apply(other) == fitted and fix.replaces(other)
    assert fix.apply(stated.scaled(320, 240)) == Correction(0.9, (4.0, -2.0), (640, 480)).apply(
        stated.scaled(320, 240)
    )
    assert Correction.of_record(fix.record()) == fix
    for value in ([600.0, 600.0, 319.5], [0.0, 600.0, 1.0, 1.0], ["a", 1, 1, 1]):
        with pytest.raises(ValueError, match='"given"'):
            Correction.of_record({**fix.record(), "given": value})


def test_a_reconstruction_corrects_wrong_intrinsics_for_every_frame(capture: Capture) -> None:
    tiny = ReconstructConfig(
        iterations=4, holdout=4, train_downscale=1, init_pixel_stride=4, sh_degree=0,
        densify_from=100, max_gaussians=3000,
    )  # fmt: skip
    given = replace(capture, frames=wrong(capture.frames, 1.1, 0.0, 0.0))
    result = fit_gaussians(given, tiny)
    entry = result.sensor["intrinsics"]
    assert entry["mode"] == "auto" and entry["applied"] is not None
    assert entry["applied"]["focal_scale"] == pytest.approx(1 / 1.1, abs=0.01)
    assert result.cameras is not None and result.cameras.intrinsics == entry["applied"]
    assert set(result.cameras.poses) == {f.name for f in capture.frames}
    off = fit_gaussians(given, replace(tiny, intrinsics_refinement="off"))
    assert off.sensor["intrinsics"]["measured"] is None
    assert off.cameras is None or off.cameras.intrinsics is None  # poses may be refined
    k = given.frames[0].intrinsics
    lens = Undistortion(Lens("opencv", (0.01, 0.0, 0.0, 0.0), "test"), k, k)
    calibrated = replace(given, frames=tuple(replace(f, undistortion=lens) for f in given.frames))
    kept = fit_gaussians(calibrated, tiny).sensor["intrinsics"]
    assert kept["measured"] is None and "lens is calibrated" in kept["not_measured"]


def test_the_option_is_validated() -> None:
    with pytest.raises(ValueError, match="intrinsics_refinement must be auto or off"):
        ReconstructConfig(intrinsics_refinement="on")


def test_the_pair_disagreement_grows_with_the_focal_error(capture: Capture) -> None:
    from dcseg.reconstruct.calibration import disagreement

    chosen = pairs(capture.frames)
    values = [
        disagreement(capture.frames, chosen, Correction(s, size=(160, 120)))
        for s in (1.0, 1.05, 1.1)
    ]
    found = [v for v in values if v is not None and np.isfinite(v)]
    assert len(found) == 3 and found == sorted(found) and found[0] < found[2] / 3
