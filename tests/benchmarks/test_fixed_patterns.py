"""fixed_patterns: a pattern every held-out view shares is found; one view's own is not."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from benchmarks.fixed_patterns import main


def _save(path: Path, seed: int, depth_factor: float, shift: int) -> None:
    """A 1.8 m wall seen by a sensor reading ``depth_factor`` too deep on the image's left
    half, with the render's colour the image's moved ``shift`` px right."""
    rng = np.random.default_rng(seed)
    render_depth = np.full((48, 64), 1.8) + rng.normal(0, 0.002, (48, 64))
    truth = render_depth.copy()
    truth[:, :32] *= depth_factor
    image = rng.uniform(size=(48, 64, 3))
    render = np.roll(image, shift, axis=1)
    np.savez_compressed(path, depth=render_depth, truth=truth, render=render, image=image)


def _report(dump: Path, tmp_path: Path) -> dict[str, Any]:
    out = tmp_path / "out.json"
    assert main([str(dump), "--grid", "2", "--colour-grid", "2", "--out", str(out)]) == 0
    report: dict[str, Any] = json.loads(out.read_text())["capture"]
    return report


def test_a_pattern_every_view_shares_is_found_and_corrected(tmp_path: Path) -> None:
    for seed in range(4):
        _save(tmp_path / f"v{seed}.npz", seed, 1.03, 2)
    report = _report(tmp_path, tmp_path)
    depth, colour = report["depth"], report["colour"]
    assert depth["depth_mae_mm"] == pytest.approx(27.0, abs=1.0)  # 3 % of 1.8 m on half
    assert depth["cross_validated_mae_mm"] < 2.0
    assert depth["largest_cell_multiplier_offset"]["1.5-2 m"] == pytest.approx(0.03, abs=0.002)
    assert colour["cross_validated_psnr"] > colour["psnr"] + 20
    assert colour["own_best_shift_psnr"] >= colour["cross_validated_psnr"]


def test_each_view_s_own_misalignment_is_not_credited(tmp_path: Path) -> None:
    for seed in range(4):
        _save(tmp_path / f"v{seed}.npz", seed, 1.0, 3 if seed % 2 else -3)
    colour = _report(tmp_path, tmp_path)["colour"]
    assert colour["cross_validated_psnr"] <= colour["psnr"] + 0.1
    assert colour["own_best_shift_psnr"] > colour["psnr"] + 20


def test_too_few_views_are_refused(tmp_path: Path) -> None:
    _save(tmp_path / "v0.npz", 0, 1.0, 0)
    with pytest.raises(SystemExit, match="two held-out views at least"):
        main([str(tmp_path)])
    with pytest.raises(SystemExit, match="no saved held-out views"):
        main([str(tmp_path / "missing")])
