"""Frames as tensors on the training device, optionally downscaled, and the hold-out split."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from dcseg.reconstruct.depth_filter import DepthFilter
from dcseg.render import Camera
from dcseg.types import Frame, Intrinsics


@dataclass(frozen=True)
class View:
    """One posed RGB-D frame as tensors.

    Attributes:
        name: the frame's name.
        camera: the renderer's camera at this view's resolution.
        rgb: ``[H, W, 3]`` float32 colour in [0, 1].
        depth: ``[H, W]`` float32 metres, 0 = invalid.
    """

    name: str
    camera: Camera
    rgb: Tensor
    depth: Tensor


def split_frames(
    frames: Sequence[Frame], holdout: int
) -> tuple[tuple[Frame, ...], tuple[Frame, ...]]:
    """``(train, test)``: frames with index ``i % holdout == 0`` are held out (0 = none)."""
    if holdout == 0 or len(frames) < 2:
        return tuple(frames), ()
    test = tuple(f for i, f in enumerate(frames) if i % holdout == 0)
    train = tuple(f for i, f in enumerate(frames) if i % holdout != 0)
    return train, test


def _downscaled(k: Intrinsics, factor: int, width: int, height: int) -> Intrinsics:
    """Intrinsics after cropping to a multiple of ``factor`` and averaging ``factor`` blocks."""
    return Intrinsics(
        fx=k.fx / factor,
        fy=k.fy / factor,
        cx=(k.cx + 0.5) / factor - 0.5,
        cy=(k.cy + 0.5) / factor - 0.5,
        width=width,
        height=height,
    )


def make_view(
    frame: Frame,
    downscale: int = 1,
    device: torch.device | str = "cpu",
    depth_filter: DepthFilter | None = None,
) -> View:
    """Tensors of ``frame``: colour area-averaged and depth sampled at block centres (denoised
    by ``depth_filter`` when given; only the sampled pixels are filtered).

    Args:
        frame: the source frame.
        downscale: integer factor; the size becomes ``(W // downscale, H // downscale)``.
        device: where the tensors live.
        depth_filter: the training views' depth filter; None = the sensor depth as it is.
    """
    rgb = torch.from_numpy(np.array(frame.rgb, dtype=np.float32) / 255.0).to(device)
    start = downscale // 2
    grid = (
        np.array(frame.depth[start::downscale, start::downscale], dtype=np.float32)
        if depth_filter is None
        else depth_filter.grid(frame.depth, downscale, start)
    )
    depth = torch.from_numpy(grid).to(device)
    intrinsics = frame.intrinsics
    if downscale > 1:
        w, h = frame.width // downscale, frame.height // downscale
        chw = rgb[: h * downscale, : w * downscale].permute(2, 0, 1).unsqueeze(0)
        rgb = F.avg_pool2d(chw, downscale).squeeze(0).permute(1, 2, 0).contiguous()
        depth = depth[:h, :w].contiguous()
        intrinsics = _downscaled(intrinsics, downscale, w, h)
    camera = Camera(
        c2w=torch.tensor(np.array(frame.c2w), dtype=torch.float32, device=device),
        K=torch.tensor(intrinsics.matrix(), dtype=torch.float32, device=device),
        width=intrinsics.width,
        height=intrinsics.height,
    )
    return View(frame.name, camera, rgb, depth)


def random_crop(view: View, fraction: float, generator: torch.Generator) -> View:
    """A random window of ``view`` covering ``fraction`` of its width and height.

    The window's camera keeps the pose and focal lengths and shifts the principal point, so
    rendering it gives exactly the same pixels as rendering the whole view and cropping.
    ``fraction >= 1`` returns ``view`` itself.
    """
    cam = view.camera
    width = max(1, min(cam.width, round(cam.width * fraction)))
    height = max(1, min(cam.height, round(cam.height * fraction)))
    if (width, height) == (cam.width, cam.height):
        return view
    x0 = int(torch.randint(0, cam.width - width + 1, (1,), generator=generator))
    y0 = int(torch.randint(0, cam.height - height + 1, (1,), generator=generator))
    k = cam.K.clone()
    k[0, 2] -= x0
    k[1, 2] -= y0
    window = Camera(cam.c2w, k, width, height)
    rgb = view.rgb[y0 : y0 + height, x0 : x0 + width]
    depth = view.depth[y0 : y0 + height, x0 : x0 + width]
    return View(view.name, window, rgb, depth)
