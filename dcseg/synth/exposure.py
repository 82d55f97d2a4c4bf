"""Auto exposure and white balance of a synthetic camera: a smooth colour gain per frame.

A handheld camera with auto exposure brightens and darkens its frames as it turns towards
darker or brighter parts of the room, and its auto white balance drifts with them; both change
slowly along the trajectory. Each frame ``i`` gets a per-channel gain ``exp(e_i + w_ic)``: the
exposure ``e`` and the white balance ``w_c`` are random smooth curves over the trajectory (a
few low-frequency sinusoids with random amplitudes and phases), scaled so that ``e`` has the
asked standard deviation over the frames and each ``w_c`` a third of it. Values saturate at
255 like a sensor's. Only colour changes; depth, masks and ground truth do not.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

MAX_SPREAD = 1.0
"""Largest exposure spread (standard deviation of the log gain) :func:`frame_gains` accepts."""

HARMONICS = 3
"""Sinusoids per curve: the slowest spans the trajectory once, the fastest three times."""

WHITE_BALANCE = 1.0 / 3.0
"""The white-balance curves' spread, as a fraction of the exposure's."""


def smooth_curve(frames: int, rng: np.random.Generator) -> NDArray[np.float64]:
    """``[frames]`` a smooth random curve with zero mean and unit standard deviation (zeros
    for a single frame)."""
    if frames < 2:
        return np.zeros(frames)
    t = np.linspace(0.0, 1.0, frames)
    curve = np.zeros(frames)
    for k in range(1, HARMONICS + 1):
        amplitude, phase = rng.normal() / k, rng.uniform(0.0, 2.0 * np.pi)
        curve += amplitude * np.sin(2.0 * np.pi * k * t + phase)
    curve -= curve.mean()
    sd = curve.std()
    return curve / sd if sd > 0 else curve


def frame_gains(frames: int, spread: float, rng: np.random.Generator) -> NDArray[np.float64]:
    """``[frames, 3]`` per-frame R, G, B gains (module docstring); all ones for spread 0."""
    if not 0.0 <= spread <= MAX_SPREAD:
        raise ValueError(f"exposure spread must be between 0 and {MAX_SPREAD:g}, got {spread}")
    if spread == 0.0:
        return np.ones((frames, 3))
    exposure = spread * smooth_curve(frames, rng)
    balance = np.stack([smooth_curve(frames, rng) for _ in range(3)], axis=1)
    balance -= balance.mean(axis=1, keepdims=True)  # white balance keeps the brightness
    return np.exp(exposure[:, None] + WHITE_BALANCE * spread * balance)


def exposed(rgb: NDArray[np.uint8], gain: NDArray[np.float64]) -> NDArray[np.uint8]:
    """``rgb`` times the per-channel ``gain``, rounded and saturated at 255."""
    if np.all(gain == 1.0):
        return rgb
    out = np.clip(np.rint(rgb.astype(np.float64) * gain), 0, 255)
    return out.astype(np.uint8)
