"""Per-view exposure and white balance: a regularised affine colour per training view.

Cameras with auto exposure and auto white balance record the same surface brighter or darker,
warmer or colder, from frame to frame. Fitted as it is, one set of Gaussian colours cannot
match every frame, and the fit blurs the difference into floaters and wrong colours. Each
training view ``v`` therefore gets a per-channel gain and bias, ``image ~ exp(g_v) * render +
b_v`` (identity at the start), learned with the Gaussians by its own Adam (a view's transform
moves only on the steps that render it) and pulled towards identity by
``exposure_reg * (|g_v|^2 + BIAS_WEIGHT |b_v|^2)``, so that it holds a global colour shift,
never scene content (a per-channel affine of a whole image cannot paint an object).

The gains have one degree of freedom the images cannot fix (a brighter scene under darker
gains); after the fit :func:`referenced` folds the views' mean transform into the Gaussians'
colours, so the exported scene holds its colours under the mean exposure (geometric mean
gain, mean bias) and the reported per-view transforms are relative to it.

Detection (:func:`colour_changes`): consecutive training frames (at most :data:`MAX_PAIRS`
pairs, evenly spread) are put into correspondence with their depth and poses, and the median
log ratio of each channel at corresponding pixels is the pair's exposure change; the view
changes the content, not the colour of a surface point, so a constant exposure measures ~0.
Held-out views have no learned transform; :func:`compensated_psnr` fits one in closed form
for the colour-compensated score.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray
from torch import Tensor

from dcseg.gaussians import SH_C0, Gaussians
from dcseg.reconstruct.stepping import AdamStepping
from dcseg.types import Frame

log = logging.getLogger(__name__)

MAX_PAIRS = 30
"""Detection measures at most this many pairs of consecutive training frames."""

SAMPLES = 5000
"""Detection projects about this many pixels of each frame (a regular grid)."""

OCCLUSION = 0.05
"""Correspondences whose projected depth is off by more than this fraction are dropped."""

LIMITS = (8.0, 247.0)
"""Correspondences need every channel inside these 8-bit values in both frames (no clipping)."""

BIAS_WEIGHT = 100.0
"""The biases are pulled towards 0 this many times harder than the log gains: auto exposure and
white balance are gains; a free bias trades with the gain (40-view synthetic scenes, spread
0.2: biases up to 0.17 and fitted log gains 0.06-0.08 off the true ones with weight 1)."""

MIN_PIXELS = 100
"""A pair with fewer correspondences is not measured."""

THRESHOLD = 0.03
"""``auto`` corrects when some pair's exposure change (largest channel, ``|log ratio|``)
exceeds this: 3 %. Measured (benchmarks/README "Exposure"): constant exposure 0.0 % (the
median ratio is exactly 1: synthetic layouts 0-2, Replica room0), the slambook2 Kinect v1
sample 4.9-7.5 % (its gains fit within 3 %), synthetic ``--exposure-spread 0.2`` up to 30 %
(median 8 %). Real fixed-exposure cameras (sensor noise, JPEG, vignetting) were not measured:
the margin above 0 is a guess at their noise in a median over thousands of pixels."""


def pair_change(src: Frame, dst: Frame) -> NDArray[np.float64] | None:
    """``[3]`` median per-channel ``log(dst / src)`` colour at pixels of ``src`` seen by ``dst``
    (grid, occlusions and clipped values dropped); None with too few correspondences."""
    grid = max(1, int(math.sqrt(src.width * src.height / SAMPLES)))
    depth = np.asarray(src.depth[::grid, ::grid], dtype=np.float64)
    rows, cols = np.nonzero(depth > 0)
    z = depth[rows, cols]
    k, kd = src.intrinsics, dst.intrinsics
    u, v = cols * grid, rows * grid
    cam = np.stack([(u - k.cx) / k.fx * z, (v - k.cy) / k.fy * z, z], axis=1)
    world = cam @ src.c2w[:3, :3].T + src.c2w[:3, 3]
    w2c = np.linalg.inv(dst.c2w)
    local = world @ w2c[:3, :3].T + w2c[:3, 3]
    zp = np.maximum(local[:, 2], 1e-6)
    x = np.rint(local[:, 0] / zp * kd.fx + kd.cx).astype(np.int64)
    y = np.rint(local[:, 1] / zp * kd.fy + kd.cy).astype(np.int64)
    inside = (local[:, 2] > 1e-6) & (x >= 0) & (x < dst.width) & (y >= 0) & (y < dst.height)
    x, y, zp, v, u = x[inside], y[inside], zp[inside], v[inside], u[inside]
    observed = np.asarray(dst.depth, dtype=np.float64)[y, x]
    seen = (observed > 0) & (np.abs(zp - observed) < OCCLUSION * observed)
    a = np.asarray(src.rgb, dtype=np.float64)[v[seen], u[seen]]
    b = np.asarray(dst.rgb, dtype=np.float64)[y[seen], x[seen]]
    low, high = LIMITS
    keep = ((a > low) & (a < high) & (b > low) & (b < high)).all(axis=1)
    if int(keep.sum()) < MIN_PIXELS:
        return None
    out: NDArray[np.float64] = np.median(np.log(b[keep] / a[keep]), axis=0)
    return out


def colour_changes(frames: Sequence[Frame]) -> dict[str, Any]:
    """Exposure changes between consecutive ``frames`` (module docstring): per measured pair
    its per-channel log ratio, the largest change (any channel, as a fraction), the median,
    and the largest white-balance change (spread between the channels' log ratios)."""
    n = len(frames) - 1
    spread = np.linspace(0, n - 1, MAX_PAIRS).round()
    starts = list(range(n)) if n <= MAX_PAIRS else sorted({int(i) for i in spread})
    ratios = [r for i in starts if (r := pair_change(frames[i], frames[i + 1])) is not None]
    return changes_summary(ratios)


def changes_summary(ratios: Sequence[NDArray[np.float64]]) -> dict[str, Any]:
    """The measured pairs' per-channel log ratios summarised: their count, the largest and
    median change (any channel, as a fraction) and the largest white-balance change."""
    if not ratios:
        return {"pairs": 0, "largest_change": None, "median_change": None, "largest_wb": None}
    logs = np.array(ratios)
    per_pair = np.abs(logs).max(axis=1)
    wb = logs.max(axis=1) - logs.min(axis=1)
    return {
        "pairs": len(ratios),
        "largest_change": float(np.expm1(per_pair.max())),
        "median_change": float(np.expm1(np.median(per_pair))),
        "largest_wb": float(np.expm1(wb.max())),
    }


def decide(mode: str, measured: dict[str, Any]) -> bool:
    """Whether the per-view transform is fitted: ``on``, ``off``, or ``auto`` when a pair
    changes by more than :data:`THRESHOLD`."""
    if mode != "auto":
        return mode == "on"
    largest = measured.get("largest_change")
    return largest is not None and math.log1p(largest) > THRESHOLD


@dataclass
class ColourCorrections(AdamStepping):
    """One learnable ``[6]`` transform per view (log gain and bias of R, G, B) and its Adam.

    Attributes:
        params: per view a ``[6]`` leaf, zero = identity.
        optimizer: Adam over them; a view's transform moves only on steps that render it.
        reg: weight of the squared distance to identity in the loss.
    """

    params: list[Tensor]
    optimizer: torch.optim.Adam
    reg: float

    @classmethod
    def identity(
        cls, n_views: int, lr: float, reg: float, device: torch.device | str
    ) -> ColourCorrections:
        params = [torch.zeros(6, device=device, requires_grad=True) for _ in range(n_views)]
        return cls(params, torch.optim.Adam(params, lr=lr, eps=1e-15), reg)

    def apply(self, index: int, image: Tensor) -> Tensor:
        """``image`` (``[H, W, 3]``) under view ``index``'s transform (differentiable)."""
        return transformed(image, self.params[index])

    def penalty(self, index: int) -> Tensor:
        """``reg * (|g|^2 + BIAS_WEIGHT |b|^2)`` of view ``index``: the pull towards identity."""
        p = self.params[index]
        return self.reg * ((p[:3] * p[:3]).sum() + BIAS_WEIGHT * (p[3:] * p[3:]).sum())


def transformed(image: Tensor, p: Tensor) -> Tensor:
    """``image`` (``[H, W, 3]``) times ``exp(p[:3])`` plus ``p[3:]``."""
    return image * torch.exp(p[:3]).to(image) + p[3:].to(image)


def interpolated(trained: Sequence[int], transforms: Tensor, held_out: Sequence[int]) -> Tensor:
    """``[len(held_out), 6]`` a transform per held-out frame, interpolated linearly in capture
    order between the trained frames around it (``trained``: their capture indices, one per row
    of ``transforms``; the nearest one past either end): auto exposure drifts smoothly in time,
    so a held-out frame's exposure is predicted without looking at its image."""
    values = transforms.detach().double().cpu().numpy()
    columns = [np.interp(held_out, trained, values[:, c]) for c in range(values.shape[1])]
    return torch.as_tensor(np.stack(columns, axis=1), dtype=transforms.dtype)


def referenced(gaussians: Gaussians, params: Sequence[Tensor]) -> tuple[Gaussians, Tensor]:
    """The Gaussians with the views' mean transform folded into their colours, and ``[V, 6]``
    every view's transform relative to that reference (log gain, bias): rendering the result
    and applying a view's relative transform gives what the fit rendered for that view
    (before the clamp of negative colours at 0)."""
    p = torch.stack([t.detach() for t in params]).to(gaussians.sh)
    ref_log, ref_bias = p[:, :3].mean(dim=0), p[:, 3:].mean(dim=0)
    gain = torch.exp(ref_log)
    sh = gaussians.sh.clone()
    # colour = 0.5 + SH_C0 dc + rest: the reference colour is gain * colour + bias.
    sh[:, 0] = (gain * (0.5 + SH_C0 * sh[:, 0]) + ref_bias - 0.5) / SH_C0
    sh[:, 1:] = sh[:, 1:] * gain
    relative_log = p[:, :3] - ref_log
    relative_bias = p[:, 3:] - torch.exp(relative_log) * ref_bias
    return replace(gaussians, sh=sh), torch.cat([relative_log, relative_bias], dim=1)


def gains_summary(transforms: Tensor, names: Sequence[str]) -> dict[str, Any]:
    """What ``reconstruction.json`` reports of the fitted per-view transforms (relative to the
    reference): the gains' range and spread per channel and every view's gain and bias."""
    gains = torch.exp(transforms[:, :3]).double().cpu().numpy()
    bias = transforms[:, 3:].double().cpu().numpy()
    return {
        "reference": "mean of the views (geometric mean gain, mean bias)",
        "gain_min": gains.min(axis=0).round(4).tolist(),
        "gain_max": gains.max(axis=0).round(4).tolist(),
        "gain_spread": float(np.log(gains).std(axis=0).max()),
        "largest_bias": float(np.abs(bias).max()),
        "views": {
            n: {"gain": g.round(4).tolist(), "bias": b.round(4).tolist()}
            for n, g, b in zip(names, gains, bias, strict=True)
        },
    }


def affine_fit(pred: Tensor, target: Tensor) -> Tensor:
    """``pred`` (``[H, W, 3]``) mapped by the 3x3 matrix plus bias that best fits ``target``
    in least squares: the colour compensation of exposure-varying benchmarks."""
    x = pred.reshape(-1, 3).double()
    x1 = torch.cat([x, torch.ones_like(x[:, :1])], dim=1)
    y = target.reshape(-1, 3).double()
    solution = torch.linalg.lstsq(x1, y).solution
    out: Tensor = (x1 @ solution).to(pred.dtype).reshape(pred.shape)
    return out


def compensated_psnr(pred: Tensor, target: Tensor) -> float:
    """PSNR (dB) of ``pred`` clamped to [0, 1], colour-compensated by :func:`affine_fit`."""
    fitted = affine_fit(pred.clamp(0.0, 1.0), target).clamp(0.0, 1.0)
    mse = float(((fitted - target) ** 2).mean())
    return math.inf if mse == 0.0 else -10.0 * math.log10(mse)


def detection_report(measured: dict[str, Any], mode: str, applied: bool) -> dict[str, Any]:
    """The ``sensor.exposure`` entries of the detection: the measured pair changes, whether
    they exceed :data:`THRESHOLD`, the configured mode and whether the transform is fitted."""
    largest = measured.get("largest_change")
    detected = largest is not None and math.log1p(largest) > THRESHOLD
    return {
        "pair_changes": measured,
        "threshold": THRESHOLD,
        "detected": detected,
        "mode": mode,
        "applied": applied,
        "fitted": None,
    }


def log_detection(report: dict[str, Any]) -> None:
    """One log line: what the detection measured and whether the transform is fitted."""
    pairs = report["pair_changes"]
    if not pairs["pairs"]:
        log.info("exposure: no overlapping frame pairs measured; per-view colour %s",
                 "fitted" if report["applied"] else "not fitted")  # fmt: skip
        return
    log.info(
        "exposure: colour at %s changes by up to %.1f %% between frames "
        "(median %.1f %%, white balance up to %.1f %%, %d pairs): %s, per-view colour %s (%s)",
        pairs.get("measured_by", "corresponding pixels"),
        100 * pairs["largest_change"],
        100 * pairs["median_change"],
        100 * pairs["largest_wb"],
        pairs["pairs"],
        "detected" if report["detected"] else "not detected",
        "fitted" if report["applied"] else "not fitted",
        report["mode"],
    )


def log_fitted(summary: dict[str, Any]) -> None:
    """One log line: the fitted gains' range per channel."""
    low, high = summary["gain_min"], summary["gain_max"]
    log.info(
        "exposure: fitted gains R %.2f-%.2f, G %.2f-%.2f, B %.2f-%.2f (largest bias %.3f)",
        low[0], high[0], low[1], high[1], low[2], high[2], summary["largest_bias"],
    )  # fmt: skip
