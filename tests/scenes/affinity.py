"""A synthetic affinity scene built by hand: groups of Gaussians covering known pixel boxes."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from numpy.typing import NDArray

from dcseg.affinity import AffinityView
from dcseg.gaussians import Gaussians
from dcseg.io.masks import masks_from_dense
from dcseg.types import AgnosticMasks
from tests.scenes.blends import blend_from_lists
from tests.scenes.gaussians import gaussians_at

HEIGHT, WIDTH = 48, 64
FOCAL = 60.0
DEPTH = 2.0
PER_GROUP = 24
CENTRES = np.array([[-2.0, 0.0, 3.0], [0.0, 0.0, 3.0], [2.0, 0.0, 3.0]])
# (row0, row1, col0, col1) of each object in view 0; later views shift right by 2 px each.
BOXES = ((10, 20, 4, 12), (14, 26, 22, 32), (12, 24, 42, 54))


def camera_matrix(
    height: int = HEIGHT, width: int = WIDTH, focal: float = FOCAL
) -> NDArray[np.float64]:
    """Pinhole ``K`` with the principal point at the image centre."""
    return np.array(
        [[focal, 0.0, (width - 1) / 2], [0.0, focal, (height - 1) / 2], [0.0, 0.0, 1.0]]
    )


def encode(dense: NDArray[np.bool_], name: str = "f") -> AgnosticMasks:
    """Dense ``[M, H, W]`` bool -> AgnosticMasks (COCO RLE, empty masks dropped)."""
    return masks_from_dense(name, dense)


def make_gaussians(rng: np.random.Generator) -> Gaussians:
    means = np.concatenate([c + rng.normal(0.0, 0.05, (PER_GROUP, 3)) for c in CENTRES])
    n = means.shape[0]
    return gaussians_at(
        torch.tensor(means, dtype=torch.float32), torch.full((n, 3), -3.0), torch.zeros(n)
    )


@dataclass(frozen=True)
class Scene:
    gaussians: Gaussians
    views: list[AffinityView]
    group: NDArray[np.int64]  # [N] object of every Gaussian


def synthetic_scene(seed: int = 0, n_views: int = 4) -> Scene:
    """3 objects (groups of 24 Gaussians), masks = objects plus one group mask of objects 1+2."""
    rng = np.random.default_rng(seed)
    gaussians = make_gaussians(rng)
    group = np.repeat(np.arange(len(CENTRES)), PER_GROUP)
    views = [_view(i, rng) for i in range(n_views)]
    return Scene(gaussians, views, group)


def _view(index: int, rng: np.random.Generator) -> AffinityView:
    dense = np.zeros((len(BOXES), HEIGHT, WIDTH), dtype=bool)
    entries: dict[int, list[tuple[int, float]]] = {}
    for k, (r0, r1, c0, c1) in enumerate(BOXES):
        dense[k, r0:r1, c0 + 2 * index : c1 + 2 * index] = True
        for p in np.flatnonzero(dense[k]):
            ids = k * PER_GROUP + rng.choice(PER_GROUP, size=4, replace=False)
            entries[int(p)] = list(zip(ids.tolist(), [0.5, 0.25, 0.15, 0.05], strict=True))
    masks = np.concatenate([dense, dense[1:2] | dense[2:3]])
    return AffinityView(
        name=f"view{index}",
        blend=blend_from_lists(HEIGHT, WIDTH, entries),
        masks=encode(masks, f"view{index}"),
        depth=np.full((HEIGHT, WIDTH), DEPTH, dtype=np.float32),
        K=camera_matrix(),
    )
