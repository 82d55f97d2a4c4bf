"""Is a held-out error a fixed pattern of the sensor? Cross-validated over held-out views.

Reads a :mod:`benchmarks.held_out_errors` dump (``DUMP/<view>.npz``: render and sensor depth,
rendered colour and image) and asks whether what the render misses repeats at the same pixels
in every view, as a sensor's own pattern would (a depth camera's per-pixel depth distortion, a
colour lens the pinhole model lacks):

- depth: a multiplier per image cell and depth band (median sensor / render depth on the
  off-edge pixels) fitted on half the views and applied to the other half;
- colour: a whole-pixel shift per image cell fitted the same way; beside it the best shift per
  cell and view, a bound that also takes each view's own misalignment (pose, geometry).

A pattern the held-out half does not share is no sensor pattern. Both folds' corrected MAE
and PSNR are pooled over the held-out halves.

    python -m benchmarks.fixed_patterns DUMP --out benchmarks/results/F.json --name capture
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from benchmarks.entries import write_entry
from benchmarks.held_out_errors import depth_edges

Array = NDArray[np.float64]

BANDS = (0.0, 1.0, 1.5, 2.0, 2.5, 3.0, 10.0)
"""Depth bands (metres) with a multiplier of their own per cell."""

MIN_PIXELS = 200
"""Fewest fitting pixels a cell and band need for a multiplier (else 1)."""

FIT_RANGE = 0.2
"""Metres of render error beyond which a pixel is a misfit, not a distortion, and is not fitted."""

REACH = 6
"""Largest shift (pixels) searched per cell; also the border left out of the colour score."""

SHIFTS = [(dx, dy) for dy in range(-REACH, REACH + 1) for dx in range(-REACH, REACH + 1)]
"""Every whole-pixel shift ``(dx, dy)`` searched per cell."""


def _load(dump: Path) -> list[dict[str, Array]]:
    views = [dict(np.load(path)) for path in sorted(dump.glob("*.npz"))]
    if not views:
        raise SystemExit(f"{dump}: no saved held-out views (*.npz)")
    return [{key: np.asarray(value, dtype=np.float64) for key, value in v.items()} for v in views]


def _cell_index(shape: tuple[int, ...], grid: int) -> NDArray[np.int64]:
    h, w = shape[:2]
    rows, cols = np.mgrid[0:h, 0:w]
    return np.asarray((rows * grid // h) * grid + cols * grid // w, dtype=np.int64)


def _multipliers(views: list[dict[str, Array]], grid: int) -> Array:
    """Median sensor / render depth per cell and band (by sensor depth), off the edges."""
    keys, ratios = [], []
    for v in views:
        render, truth = v["depth"], v["truth"]
        use = (truth > 0) & (render > 0) & ~depth_edges(truth)
        use &= np.abs(render - truth) < FIT_RANGE
        band = np.digitize(truth[use], BANDS) - 1
        keys.append(_cell_index(truth.shape, grid)[use] * len(BANDS) + band)
        ratios.append(truth[use] / render[use])
    key, ratio = np.concatenate(keys), np.concatenate(ratios)
    table = np.ones(grid * grid * len(BANDS))
    for k in np.unique(key):
        chosen = ratio[key == k]
        if chosen.size >= MIN_PIXELS:
            table[k] = np.median(chosen)
    return table


def _depth_sums(views: list[dict[str, Array]], table: Array, grid: int) -> tuple[float, float]:
    """Absolute depth error summed over the sensor's pixels as rendered and with ``table``
    applied (band by the render's own depth: the correction never sees the sensor)."""
    before = after = 0.0
    for v in views:
        render, truth = v["depth"], v["truth"]
        band = np.clip(np.digitize(render, BANDS) - 1, 0, len(BANDS) - 2)
        factor = table[_cell_index(truth.shape, grid) * len(BANDS) + band]
        valid = truth > 0
        before += float(np.abs(render - truth)[valid].sum())
        after += float(np.abs(render * factor - truth)[valid].sum())
    return before, after


def _halves(count: int) -> list[tuple[list[int], list[int]]]:
    even, odd = list(range(0, count, 2)), list(range(1, count, 2))
    return [(even, odd), (odd, even)]


def depth_pattern(views: list[dict[str, Array]], grid: int) -> dict[str, Any]:
    """The depth error with and without a per-cell multiplier fitted on the other half."""
    pixels = sum(int((v["truth"] > 0).sum()) for v in views)
    before = after = 0.0
    for fit, test in _halves(len(views)):
        table = _multipliers([views[i] for i in fit], grid)
        b, a = _depth_sums([views[i] for i in test], table, grid)
        before, after = before + b, after + a
    whole = _multipliers(views, grid).reshape(grid * grid, len(BANDS))
    spread = {
        f"{BANDS[i]:g}-{BANDS[i + 1]:g} m": float(np.abs(whole[:, i] - 1).max())
        for i in range(len(BANDS) - 1)
    }
    return {
        "depth_mae_mm": 1e3 * before / pixels,
        "cross_validated_mae_mm": 1e3 * after / pixels,
        "largest_cell_multiplier_offset": spread,
    }


def _shift_errors(view: dict[str, Array], grid: int) -> Array:
    """Squared colour error per cell (rows) and shift (columns, :data:`SHIFTS` order)."""
    render, image = np.clip(view["render"], 0, 1), view["image"]
    h, w = image.shape[:2]
    inner_h, inner_w = h - 2 * REACH, w - 2 * REACH
    errors = np.zeros((grid * grid, len(SHIFTS)))
    for cell in range(grid * grid):
        y0 = REACH + (cell // grid) * inner_h // grid
        y1 = REACH + (cell // grid + 1) * inner_h // grid
        x0 = REACH + (cell % grid) * inner_w // grid
        x1 = REACH + (cell % grid + 1) * inner_w // grid
        core = image[y0:y1, x0:x1]
        for k, (dx, dy) in enumerate(SHIFTS):
            moved = render[y0 + dy : y1 + dy, x0 + dx : x1 + dx]
            errors[cell, k] = float(((moved - core) ** 2).sum())
    return errors


def colour_pattern(views: list[dict[str, Array]], grid: int) -> dict[str, Any]:
    """Mean held-out PSNR (interior) as rendered, with a per-cell shift fitted on the other
    half, and with each view's own best shift per cell (a bound, not a prediction)."""
    errors = np.stack([_shift_errors(v, grid) for v in views])  # view x cell x shift
    samples = sum(v["image"][REACH:-REACH, REACH:-REACH].size for v in views) / len(views)
    still = SHIFTS.index((0, 0))
    cells = np.arange(grid * grid)
    fixed = np.zeros(len(views))
    for fit, test in _halves(len(views)):
        best = errors[fit].sum(axis=0).argmin(axis=1)
        fixed[test] = errors[test][:, cells, best].sum(axis=1)

    def psnr(squared: Array) -> float:
        return float(np.mean(-10.0 * np.log10(np.maximum(squared / samples, 1e-10))))

    return {
        "psnr": psnr(errors[:, :, still].sum(axis=1)),
        "cross_validated_psnr": psnr(fixed),
        "own_best_shift_psnr": psnr(errors.min(axis=2).sum(axis=1)),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dump", type=Path)
    parser.add_argument("--grid", type=int, default=8, help="cells per side (depth)")
    parser.add_argument("--colour-grid", type=int, default=5, help="cells per side (colour)")
    parser.add_argument("--out", type=Path)
    parser.add_argument("--name", default="capture")
    args = parser.parse_args(argv)
    views = _load(args.dump)
    if len(views) < 2:
        raise SystemExit(f"{args.dump}: two held-out views at least are needed to cross-validate")
    report = {
        "views": len(views),
        "depth": depth_pattern(views, args.grid),
        "colour": colour_pattern(views, args.colour_grid),
    }
    print(json.dumps(report, indent=1))
    if args.out:
        write_entry(args.out, args.name, report)
    return 0


if __name__ == "__main__":
    sys.exit(main())
