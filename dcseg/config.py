"""Method and reader parameters as plain stdlib dataclasses.

This module must never import torch: the HTTP service imports it to describe job options.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class CaptureOptions:
    """Options every capture reader honours.

    Attributes:
        stride: keep every ``stride``-th frame (1 = all).
        max_frames: keep at most this many frames after striding (None = all).
        size: target ``(width, height)``; images are downscaled (area filter), depth is
            resampled with nearest neighbour and intrinsics are scaled to match. None = native.
        depth_trunc: depth beyond this many metres is set to 0 (invalid). None = keep all.
        intrinsics: ``(fx, fy, cx, cy)`` at the native colour resolution, for layouts that do
            not store intrinsics (7-Scenes, Replica without ``cam_params.json``).
    """

    stride: int = 1
    max_frames: int | None = None
    size: tuple[int, int] | None = None
    depth_trunc: float | None = None
    intrinsics: tuple[float, float, float, float] | None = None

    def __post_init__(self) -> None:
        if self.stride < 1:
            raise ValueError(f"stride must be >= 1, got {self.stride}")
        if self.max_frames is not None and self.max_frames < 1:
            raise ValueError(f"max_frames must be >= 1, got {self.max_frames}")
        if self.size is not None and (self.size[0] < 1 or self.size[1] < 1):
            raise ValueError(f"size must be positive, got {self.size}")
        if self.depth_trunc is not None and self.depth_trunc <= 0:
            raise ValueError(f"depth_trunc must be > 0, got {self.depth_trunc}")
