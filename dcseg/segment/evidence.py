"""How much each Gaussian's own class-mask evidence agrees with its cluster's class.

A Gaussian's evidence for class ``c`` in one view is its blending weight summed over the
pixels the class-aware map labels ``c``: a sparse product over the view's frozen blending
weights, like the cluster maps (:mod:`dcseg.segment.maps`). Only two numbers per Gaussian are
kept by :func:`class_agreement` — the evidence for the class of its cluster and for any class —
so memory is O(N), whatever the vocabulary's size. :func:`class_evidence` keeps the whole
``[N, C]`` table, and :func:`vote_3d` turns it into the training-free 3D vote (each Gaussian
takes the class with the largest summed weight: FlashSplat-style lifting of the 2D maps).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray

from dcseg.blend import BlendWeights


def view_agreement(
    blend: BlendWeights, class_map: NDArray[Any], gaussian_classes: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """One view's evidence per Gaussian: ``(agree [N], total [N])`` float64.

    On the CPU a numba pass over the stored contributions
    (:func:`dcseg.blend_kernels.add_class_agreement`), elsewhere :func:`agreement_torch`.

    Args:
        blend: the view's blending weights.
        class_map: ``[H, W]`` int class per pixel, -1 = none.
        gaussian_classes: ``[N]`` int64 class of every Gaussian's cluster, -1 = none, on the
            blending weights' device.

    Returns:
        ``agree``: blending weight over pixels labelled with the Gaussian's own class;
        ``total``: blending weight over pixels labelled with any class.
    """
    if np.shape(class_map) != (blend.height, blend.width):
        raise ValueError(
            f"class map {np.shape(class_map)} does not match the view's "
            f"{(blend.height, blend.width)}"
        )
    classes = np.asarray(class_map, dtype=np.int64).reshape(-1)
    if blend.ids.device.type != "cpu":
        return agreement_torch(
            blend, torch.as_tensor(classes, device=blend.ids.device), gaussian_classes
        )
    from dcseg.blend_kernels import add_class_agreement

    n = gaussian_classes.shape[0]
    agree, total = np.zeros(n), np.zeros(n)
    add_class_agreement(
        blend.offsets.numpy(),
        blend.ids.numpy(),
        blend.weights.detach().numpy(),
        classes,
        gaussian_classes.numpy(),
        agree,
        total,
    )
    return torch.from_numpy(agree), torch.from_numpy(total)


def agreement_torch(
    blend: BlendWeights, pixel_class: torch.Tensor, gaussian_classes: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`view_agreement` with tensor operations on any device (``pixel_class`` ``[H*W]``)."""
    pixel_class = pixel_class[blend.rows()]
    ids = blend.ids.long()
    weights = blend.weights.double()
    seen = pixel_class >= 0
    own = seen & (pixel_class == gaussian_classes[ids])
    n = gaussian_classes.shape[0]
    return _sum_by(ids[own], weights[own], n), _sum_by(ids[seen], weights[seen], n)


def _sum_by(ids: torch.Tensor, weights: torch.Tensor, n: int) -> torch.Tensor:
    return torch.zeros(n, dtype=weights.dtype, device=weights.device).index_add_(0, ids, weights)


def class_agreement(
    blends: Sequence[BlendWeights],
    class_maps: Sequence[NDArray[Any]],
    gaussian_classes: NDArray[np.integer[Any]],
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Per Gaussian, class-mask evidence for its cluster's class and for any class, over views.

    Args:
        blends: per view, the blending weights.
        class_maps: per view, ``[H, W]`` int class per pixel (-1 = none), same views in order.
        gaussian_classes: ``[N]`` class of every Gaussian's cluster (-1 = none): the cluster
            labels mapped through the assignment.

    Returns:
        ``agree [N]`` and ``total [N]`` float64, summed over views (see :func:`view_agreement`).

    Example:
        >>> agree, total = class_agreement(blends, maps, classes)  # doctest: +SKIP
        >>> share = agree / np.maximum(total, 1e-12)
    """
    if len(blends) != len(class_maps):
        raise ValueError(f"{len(blends)} blending-weight views but {len(class_maps)} class maps")
    classes = torch.from_numpy(np.asarray(gaussian_classes, dtype=np.int64))
    n = len(classes)
    agree, total = np.zeros(n), np.zeros(n)
    for i, (blend, class_map) in enumerate(zip(blends, class_maps, strict=True)):
        try:
            a, t = view_agreement(blend, class_map, classes.to(blend.ids.device))
        except ValueError as error:
            raise ValueError(f"view {i}: {error}") from None
        agree += a.cpu().numpy()
        total += t.cpu().numpy()
    return agree, total


def view_evidence(blend: BlendWeights, class_map: NDArray[Any], n_classes: int) -> torch.Tensor:
    """One view's ``[N_ids, C]`` float64 evidence: weight per Gaussian over pixels of each class.

    Rows cover the Gaussians ``0 .. max(ids)``; :func:`class_evidence` pads them to N.

    Args:
        blend: the view's blending weights.
        class_map: ``[H, W]`` int class per pixel, -1 = none, every class below ``n_classes``.
        n_classes: C.
    """
    n = int(blend.ids.max()) + 1 if blend.nnz else 0
    evidence = np.zeros((n, n_classes))
    add_view_evidence(blend, class_map, evidence)
    return torch.from_numpy(evidence).to(blend.ids.device)


def add_view_evidence(
    blend: BlendWeights, class_map: NDArray[Any], evidence: NDArray[np.float64]
) -> None:
    """Add one view's evidence (:func:`view_evidence`) into ``evidence`` ``[N, C]`` in place:
    on the CPU the kernel adds into it directly, so no per-view ``[N, C]`` table is allocated,
    zeroed and added (fresh memory per view, ~11 MB at 120k Gaussians and 12 classes)."""
    n, n_classes = evidence.shape
    classes = _checked_classes(blend, class_map, n_classes)
    top = int(blend.ids.max()) if blend.nnz else -1
    if top >= n:
        raise ValueError(f"Gaussian ids go up to {top} but n = {n}")
    if blend.ids.device.type != "cpu":
        pixel = torch.as_tensor(classes, device=blend.ids.device)
        evidence[: top + 1] += evidence_torch(blend, pixel, top + 1, n_classes).cpu().numpy()
        return
    from dcseg.blend_kernels import add_class_evidence

    add_class_evidence(
        blend.offsets.numpy(), blend.ids.numpy(), blend.weights.detach().numpy(), classes, evidence
    )


def _checked_classes(blend: BlendWeights, class_map: NDArray[Any], n_classes: int) -> NDArray[Any]:
    if np.shape(class_map) != (blend.height, blend.width):
        raise ValueError(
            f"class map {np.shape(class_map)} does not match the view's "
            f"{(blend.height, blend.width)}"
        )
    classes = np.asarray(class_map, dtype=np.int64).reshape(-1)
    if classes.size and (classes.min() < -1 or classes.max() >= n_classes):
        raise ValueError(f"class map values must be in [-1, {n_classes}), got {classes.max()}")
    return classes


def evidence_torch(
    blend: BlendWeights, pixel_class: torch.Tensor, n: int, n_classes: int
) -> torch.Tensor:
    """:func:`view_evidence` with tensor operations on any device (``pixel_class`` ``[H*W]``)."""
    pixel_class = pixel_class[blend.rows()]
    seen = pixel_class >= 0
    ids = blend.ids.long()[seen]
    flat = ids * n_classes + pixel_class[seen]
    out = torch.zeros(n * n_classes, dtype=torch.float64, device=blend.ids.device)
    out = out.index_add_(0, flat, blend.weights.double()[seen])
    return out.reshape(n, n_classes)


class EvidenceSum:
    """``[N, C]`` class evidence summed one view at a time (:func:`class_evidence`), so a pass
    over the views that does other work per view (the pipeline's cluster maps) adds it without
    reading the views' weights again."""

    def __init__(self, n: int, n_classes: int) -> None:
        self.evidence = np.zeros((n, n_classes))
        self.seen = np.zeros(n)
        """``[N]`` each Gaussian's blending weight over every pixel of the summed views."""
        self.views = 0

    def add(self, blend: BlendWeights, class_map: NDArray[Any]) -> None:
        """Add one view; errors name the view by its position in the sum."""
        i, self.views = self.views, self.views + 1
        try:
            add_view_evidence(blend, class_map, self.evidence)
        except ValueError as error:
            raise ValueError(f"view {i}: {error}") from None
        n = len(self.seen)
        self.seen += _sum_by(blend.ids.long(), blend.weights.detach().double(), n).cpu().numpy()

    def unlabelled_share(self) -> NDArray[np.float64]:
        """``[N]`` share of each Gaussian's weight that fell on pixels the class maps leave
        unlabelled (0 for a Gaussian no view saw)."""
        unlabelled = np.maximum(self.seen - self.evidence.sum(axis=1), 0.0)
        share: NDArray[np.float64] = np.divide(
            unlabelled, self.seen, out=np.zeros_like(self.seen), where=self.seen > 0
        )
        return share


def class_evidence(
    blends: Sequence[BlendWeights], class_maps: Sequence[NDArray[Any]], n: int, n_classes: int
) -> NDArray[np.float64]:
    """Per Gaussian and class, the blending weight summed over the class-aware maps of all views.

    ``evidence[g, c]`` is the weight Gaussian ``g`` contributes to pixels the class-aware map
    labels ``c``, summed over views; a row of zeros means ``g`` never reaches a labelled pixel.
    Views are read one at a time (``blends`` may be a sequence that reads each on access).

    Args:
        blends: per view, the blending weights.
        class_maps: per view, ``[H, W]`` int class per pixel (-1 = none), same views in order.
        n: N, the number of Gaussians.
        n_classes: C, the vocabulary's size.

    Returns:
        ``[N, C]`` float64 evidence.

    Example:
        >>> evidence = class_evidence(blends, maps, n, n_classes)  # doctest: +SKIP
        >>> labels = vote_3d(evidence)
    """
    if len(blends) != len(class_maps):
        raise ValueError(f"{len(blends)} blending-weight views but {len(class_maps)} class maps")
    total = EvidenceSum(n, n_classes)
    for blend, class_map in zip(blends, class_maps, strict=True):
        total.add(blend, class_map)
    return total.evidence


def vote_3d(evidence: NDArray[Any], min_evidence: float = 0.0) -> NDArray[np.int64]:
    """The training-free 3D vote: each Gaussian takes its class of largest summed weight.

    Args:
        evidence: ``[N, C]`` from :func:`class_evidence`.
        min_evidence: a Gaussian whose evidence over all classes is at most this gets -1
            (0: only Gaussians that never reach a labelled pixel stay unlabelled).

    Returns:
        ``[N]`` int64 class (ties go to the lower index), -1 = none.
    """
    table = np.asarray(evidence, dtype=np.float64)
    if table.ndim != 2:
        raise ValueError(f"evidence must be [N, C], got shape {table.shape}")
    if table.shape[1] == 0:
        return np.full(table.shape[0], -1, dtype=np.int64)
    best = table.argmax(axis=1)
    return np.where(table.sum(axis=1) > min_evidence, best, -1).astype(np.int64)
