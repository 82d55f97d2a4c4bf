"""The projection protocol over a trained scene's views: label images voted onto GT points.

:func:`~dcseg.evaluate.points.vote_projection` takes per-view depth, intrinsics and poses. A
run's views (:class:`dcseg.io.run_state.ViewState`) may read their depth from the cache folder
on every access, so :func:`view_depths` hands them over one view at a time: no step holds
every view's depth.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, TypeVar, overload

import numpy as np
from numpy.typing import NDArray

from dcseg.evaluate.points import vote_projection

if TYPE_CHECKING:
    from dcseg.io.run_state import ViewState
    from dcseg.types import GroundTruth

T = TypeVar("T")


class _PerView(Sequence[T]):
    """One value per view, read as the views are iterated (one view's value held at a time)."""

    def __init__(self, views: Sequence[ViewState], read: Callable[[ViewState], T]) -> None:
        self._views = views
        self._read = read

    def __len__(self) -> int:
        return len(self._views)

    @overload
    def __getitem__(self, index: int) -> T: ...
    @overload
    def __getitem__(self, index: slice) -> Sequence[T]: ...
    def __getitem__(self, index: int | slice) -> T | Sequence[T]:
        if isinstance(index, slice):
            return _PerView(self._views[index], self._read)
        return self._read(self._views[index])


def view_depths(views: Sequence[ViewState]) -> Sequence[NDArray[np.float32]]:
    """The views' depth, read one view at a time as they are iterated."""
    return _PerView(views, lambda v: v.depth)


def vote_views(
    gt: GroundTruth,
    views: Sequence[ViewState],
    images: Sequence[NDArray[Any]],
    n_classes: int,
    depth_tol: float,
) -> NDArray[np.int64]:
    """``[P]`` class per ground-truth point (-1 = no vote): the label ``images`` (one
    ``[H, W]`` per view of ``views``) voted onto ``gt.points`` with each view's depth test
    (:func:`~dcseg.evaluate.points.vote_projection`)."""
    return vote_projection(
        gt.points,
        images,
        view_depths(views),
        [v.K for v in views],
        [v.c2w for v in views],
        n_classes,
        depth_tol,
    )
