"""The optimiser steps shared by the per-view corrections trained beside the Gaussians
(:class:`~dcseg.reconstruct.poses.PoseCorrections`,
:class:`~dcseg.reconstruct.exposure.ColourCorrections`): each has its own Adam whose learning
rate follows the reconstruction's schedule."""

from __future__ import annotations

import torch


class AdamStepping:
    """``set_lr`` and ``step`` over the subclass's ``optimizer``."""

    optimizer: torch.optim.Adam

    def set_lr(self, lr: float) -> None:
        for group in self.optimizer.param_groups:
            group["lr"] = lr

    def step(self) -> None:
        self.optimizer.step()
        self.optimizer.zero_grad(set_to_none=True)
