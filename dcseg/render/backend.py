"""Which rasterizer backend to use: explicit argument > ``DCSEG_RENDER_BACKEND`` > device."""

from __future__ import annotations

import importlib.util
import logging
import os

import torch

logger = logging.getLogger(__name__)

BACKENDS = ("cpu", "gsplat", "reference")
"""Backend names: numba CPU kernels, gsplat CUDA kernels, pure-PyTorch reference."""
BACKEND_ENV = "DCSEG_RENDER_BACKEND"
"""Environment variable overriding the device default (the ``backend`` argument wins)."""


def select_backend(device: torch.device, requested: str | None = None) -> str:
    """The backend to render tensors on ``device`` with.

    Args:
        device: where the Gaussians live.
        requested: an explicit backend name, or None for the env var / device default.

    Returns:
        One of :data:`BACKENDS`.

    Raises:
        ValueError: unknown name, or a backend that cannot run on ``device``.
    """
    name = requested or os.environ.get(BACKEND_ENV) or _default_backend(device)
    if name not in BACKENDS:
        raise ValueError(f"unknown render backend {name!r}; choose one of {', '.join(BACKENDS)}")
    if name == "gsplat" and device.type != "cuda":
        raise ValueError(f"render backend 'gsplat' needs CUDA tensors, got device {device}")
    if name == "cpu" and device.type != "cpu":
        raise ValueError(f"render backend 'cpu' needs CPU tensors, got device {device}")
    return name


def _default_backend(device: torch.device) -> str:
    if device.type == "cpu":
        return "cpu"
    if device.type == "cuda" and gsplat_available():
        return "gsplat"
    logger.warning("gsplat is not importable; rendering on %s with the slow reference", device)
    return "reference"


def gsplat_available() -> bool:
    """Whether the optional ``gsplat`` package can be imported."""
    return importlib.util.find_spec("gsplat") is not None
