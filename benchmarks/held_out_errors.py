"""Where a reconstruction's held-out depth error and PSNR come from (a real capture's anatomy).

``run`` reconstructs a capture with ``dcseg reconstruct`` (the arguments after ``--`` as given
to it) and saves, per held-out view, the rendered colour (``[H, W, 3]``) and depth beside the
view's own (``DUMP/<view>.npz``; tens of MB, never committed). ``summarise`` reads them and
reports what the mean absolute depth error is made of: its median and tail, the share of
depth-edge pixels (sensor depth ranging more than ``EDGE_RANGE`` in a 5x5 window) and what
they contribute, the error by distance, and whether a whole-image shift of the render (a
residual pose or registration error) would lower the depth error or raise the PSNR (both
over the image less a ``SHIFT``-pixel border). ``run`` also saves the nearest training frames'
depth warped into each held-out view (:mod:`benchmarks.neighbour_depth`), and ``summarise``
sets the render against that trivial baseline on the pixels both have, and against single
training frames ever further away (``one_training_frame_at_gap``), and counts how far the
render's silhouettes spill past the sensor's (:mod:`benchmarks.silhouettes`).

    python -m benchmarks.held_out_errors run DUMP -- CAPTURE --intrinsics 585,585,320,240 --out O
    python -m benchmarks.held_out_errors summarise DUMP --out benchmarks/results/F.json
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from benchmarks import neighbour_depth, silhouettes
from benchmarks.entries import write_entry

EDGE_RANGE = 0.05
"""Metres of sensor depth range in a 5x5 window that make a pixel a depth-edge pixel."""

TAILS = (0.05, 0.1, 0.2, 0.5)
"""Error thresholds (metres) whose pixel share and MAE contribution are reported."""

RENDER = "render_view"
"""The renderer :mod:`dcseg.reconstruct.evaluate` imports; ``run`` wraps it to keep renders."""

OBSERVED = "_observed"
"""The stage's step that sees the registered training and held-out frames at their final
poses; ``run`` wraps it to warp the training frames' depth into each held-out one
(:mod:`benchmarks.neighbour_depth`, saved as ``neighbour``)."""

SHIFT = 4
"""Largest whole-image shift (pixels) of the render searched per view."""


def run(dump: Path, argv: list[str]) -> int:
    """``dcseg reconstruct ARGV`` with every held-out view's render saved to ``dump`` (the
    render :func:`dcseg.reconstruct.evaluate.evaluate_view` scores, kept as it passes)."""
    import dcseg.reconstruct.evaluate as evaluate
    import dcseg.reconstruct.stage as stage
    from dcseg.cli import main

    dump.mkdir(parents=True, exist_ok=True)
    score, draw = evaluate.evaluate_view, getattr(evaluate, RENDER)
    seen = getattr(stage, OBSERVED)
    last: list[Any] = []
    warps: dict[str, NDArray[np.float32]] = {}

    def warping(capture: Any, train: Any, test: Any, poses: Any) -> Any:
        order = {f.name: i for i, f in enumerate(capture.frames)}
        posed = [replace(f, c2w=(poses or {}).get(f.name, f.c2w)) for f in train]
        for frame in test if capture.has_depth else ():
            warps[frame.name] = neighbour_depth.warped(
                frame, neighbour_depth.nearest(frame, posed, order)
            )
            for gap in neighbour_depth.GAPS:
                source = neighbour_depth.at_gap(frame, posed, order, gap)
                if source is not None:
                    warps[f"{frame.name}/gap{gap}"] = neighbour_depth.projected(frame, source)
        return seen(capture, train, test, poses)

    def keeping(*args: Any, **kw: Any) -> Any:
        last[:] = [draw(*args, **kw)]
        return last[0]

    def saving(gaussians: Any, view: Any, degree: int, backend: Any, **kw: Any) -> Any:
        metrics = score(gaussians, view, degree, backend, **kw)
        out = last[0]
        extra: dict[str, Any] = {"neighbour": warps[view.name]} if view.name in warps else {}
        for gap in neighbour_depth.GAPS:
            if f"{view.name}/gap{gap}" in warps:
                extra[f"gap{gap}"] = warps[f"{view.name}/gap{gap}"]
        np.savez_compressed(
            dump / f"{view.name}.npz", depth=out.depth.cpu().numpy().squeeze(),
            truth=view.depth.cpu().numpy().squeeze(), render=out.values.cpu().numpy(),
            image=view.rgb.cpu().numpy(), **extra,
        )  # fmt: skip
        return metrics

    evaluate.evaluate_view = saving  # type: ignore[assignment]
    setattr(evaluate, RENDER, keeping)
    setattr(stage, OBSERVED, warping)
    try:
        return main(["reconstruct", *argv])
    finally:
        evaluate.evaluate_view = score  # type: ignore[assignment]
        setattr(evaluate, RENDER, draw)
        setattr(stage, OBSERVED, seen)


def depth_edges(truth: NDArray[Any]) -> NDArray[np.bool_]:
    """Pixels whose 5x5 window of sensor depth ranges more than :data:`EDGE_RANGE`."""
    valid = truth > 0
    high = ndimage.maximum_filter(np.where(valid, truth, 0.0), 5)
    low = ndimage.minimum_filter(np.where(valid, truth, np.inf), 5)
    return np.asarray((high - low) > EDGE_RANGE)


def _best_shift(a: NDArray[Any], b: NDArray[Any], cost: Any) -> tuple[float, float, int, int]:
    """``cost(a, b)`` unshifted and at the best shift within :data:`SHIFT` px, and that shift:
    ``a`` read ``(dx, dy)`` px right and down of each pixel of ``b``."""
    h, w = b.shape[:2]
    m = SHIFT
    core = b[m : h - m, m : w - m]
    scores = {
        (dx, dy): cost(a[m + dy : h - m + dy, m + dx : w - m + dx], core)
        for dy in range(-m, m + 1)
        for dx in range(-m, m + 1)
    }
    (dx, dy), best = min(scores.items(), key=lambda item: item[1])
    return scores[(0, 0)], best, dx, dy


def _depth_cost(rendered: NDArray[Any], truth: NDArray[Any]) -> float:
    return float(np.abs(rendered - truth)[truth > 0].mean())


def _colour_cost(rendered: NDArray[Any], image: NDArray[Any]) -> float:
    return float(((np.clip(rendered, 0, 1) - image) ** 2).mean())  # MSE: lower is better


def _psnr(mse: float) -> float:
    return -10.0 * float(np.log10(max(mse, 1e-10)))


def summarise(dump: Path) -> dict[str, Any]:
    """The anatomy of the held-out errors saved in ``dump`` (module docstring)."""
    errors, edges, depths, views = [], [], [], []
    against: list[dict[str, float]] = []
    gaps: dict[int, list[tuple[NDArray[np.float32], NDArray[np.float32]]]] = {}
    spilled = np.zeros((len(silhouettes.DISTANCES), 4), dtype=np.int64)
    for path in sorted(dump.glob("*.npz")):
        saved = np.load(path)
        rendered, truth = saved["depth"], saved["truth"]
        spilled += silhouettes.counts(rendered, truth, saved.get("neighbour"))
        if "neighbour" in saved:
            against.append(neighbour_depth.compared(rendered, truth, saved["neighbour"]))
        for gap in neighbour_depth.GAPS:
            if f"gap{gap}" in saved:
                gaps.setdefault(gap, []).append(
                    neighbour_depth.by_gap(rendered, truth, saved[f"gap{gap}"])
                )
        valid = truth > 0
        errors.append(np.abs(rendered - truth)[valid])
        edges.append(depth_edges(truth)[valid])
        depths.append(truth[valid])
        d0, d1, dx, dy = _best_shift(rendered, truth, _depth_cost)
        c0, c1, cx, cy = _best_shift(saved["render"], saved["image"], _colour_cost)
        views.append({
            "view": path.stem, "depth_mae_mm": 1e3 * d0, "shifted_depth_mae_mm": 1e3 * d1,
            "depth_shift_px": [dx, dy], "psnr": _psnr(c0), "shifted_psnr": _psnr(c1),
            "colour_shift_px": [cx, cy],
        })  # fmt: skip
    if not views:
        raise SystemExit(f"{dump}: no saved held-out views (*.npz)")
    error, edge, depth = np.concatenate(errors), np.concatenate(edges), np.concatenate(depths)
    mm = 1e3
    by_depth = {}
    for low, high in ((0, 1), (1, 2), (2, 3), (3, 10)):
        inside = (depth >= low) & (depth < high)
        if inside.any():
            by_depth[f"{low}-{high} m"] = {
                "share": float(inside.mean()), "mae_mm": mm * float(error[inside].mean()),
                "median_mm": mm * float(np.median(error[inside])),
            }  # fmt: skip
    return {
        "views": len(views),
        "depth_pixels": int(error.size),
        "depth_mae_mm": mm * float(error.mean()),
        "depth_median_mm": mm * float(np.median(error)),
        "depth_p90_mm": mm * float(np.percentile(error, 90)),
        "edge_share": float(edge.mean()),
        "edge_mae_mm": mm * float(error[edge].mean()) if edge.any() else None,
        "off_edge_mae_mm": mm * float(error[~edge].mean()) if (~edge).any() else None,
        "edge_contribution_mm": mm * float((error * edge).mean()),
        "tails": {
            f">{t} m": {
                "share": float((error > t).mean()),
                "contribution_mm": mm * float((error * (error > t)).mean()),
            }
            for t in TAILS
        },
        "by_sensor_depth": by_depth,
        "mean_shifted_depth_mae_mm": float(np.mean([v["shifted_depth_mae_mm"] for v in views])),
        "mean_view_depth_mae_mm": float(np.mean([v["depth_mae_mm"] for v in views])),
        "mean_psnr": float(np.mean([v["psnr"] for v in views])),
        "mean_shifted_psnr": float(np.mean([v["shifted_psnr"] for v in views])),
        "neighbour_depth": _against(against),
        "silhouettes": silhouettes.summary(spilled),
        "one_training_frame_at_gap": {
            str(gap): neighbour_depth.gap_summary(
                np.concatenate([w for w, _ in pairs]), np.concatenate([r for _, r in pairs])
            )
            for gap, pairs in sorted(gaps.items())
        },
        "per_view": views,
    }


def _against(sums: list[dict[str, float]]) -> dict[str, float] | None:
    """The render against the nearest training frames' warped depth, on the pixels both have
    (None when the dump has no warps)."""
    total = {key: sum(s[key] for s in sums) for key in sums[0]} if sums else None
    if total is None or total["pixels"] == 0:
        return None
    return {
        "share": total["pixels"] / total["valid"],
        "warp_mae_mm": 1e3 * total["warp_abs"] / total["pixels"],
        "render_mae_mm": 1e3 * total["render_abs"] / total["pixels"],
        "render_tail_share": total["render_tail"] / total["pixels"],
        "tail_where_warp_agrees": (
            total["tail_warp_agrees"] / total["render_tail"] if total["render_tail"] else 0.0
        ),
    }


def main(argv: list[str] | None = None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    if args[:1] == ["run"] and "--" in args:
        split = args.index("--")
        if split != 2:
            raise SystemExit("usage: held_out_errors run DUMP -- RECONSTRUCT ARGS")
        return run(Path(args[1]), args[split + 1 :])
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("command", choices=["summarise"])
    parser.add_argument("dump", type=Path)
    parser.add_argument("--out", type=Path)
    parser.add_argument("--name", default="capture")
    parsed = parser.parse_args(args)
    report = summarise(parsed.dump)
    summary = {k: v for k, v in report.items() if k != "per_view"}
    print(json.dumps(summary, indent=1))
    if parsed.out:
        write_entry(parsed.out, parsed.name, report)
    return 0


if __name__ == "__main__":
    sys.exit(main())
