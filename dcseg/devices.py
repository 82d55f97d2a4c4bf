"""Which torch device a command computes on: ``auto`` (CUDA when present), ``cpu``, ``cuda``."""

from __future__ import annotations

import re

import torch

DEVICE_CHOICES = ("auto", "cpu", "cuda")
"""What ``--device`` accepts (``cuda:N`` picks one GPU)."""

_PATTERN = re.compile(r"^(auto|cpu|cuda(:\d+)?)$")


def resolve_device(name: str) -> torch.device:
    """The device ``name`` stands for; ValueError for an unknown name or a missing GPU.

    Reconstruction, the blend-weight cache's projection and affinity training follow it; the
    cache itself stays in host memory (one view at a time is moved to the device).
    """
    if not _PATTERN.match(name):
        raise ValueError(f"unknown device {name!r}; choose auto, cpu, cuda or cuda:N")
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    device = torch.device(name)
    if device.type == "cuda":
        if not torch.cuda.is_available():
            raise ValueError(f"device {name!r} asked for, but torch sees no CUDA device")
        if device.index is not None and device.index >= torch.cuda.device_count():
            count = torch.cuda.device_count()
            raise ValueError(f"device {name!r} asked for, but torch sees {count} CUDA device(s)")
    return device
