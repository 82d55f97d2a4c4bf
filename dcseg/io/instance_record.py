"""One record of ``instances.json``, kept apart from the writers so that readers of the file
(the HTTP API's ``InstancePublic`` is built from these fields) import no image libraries."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class InstanceRecord:
    """One segmented object: a cluster of Gaussians and the class it was assigned.

    The one declaration of the record: the API's ``InstancePublic`` takes its fields from here,
    so a field added here is served without a second edit."""

    id: int
    """Instance id (``instance_id`` in ``scene_labelled.ply``); ids start at 1."""
    label: str | None
    """Class name; None = unlabelled."""
    label_id: int
    """Index of the class in ``labels.json``; -1 = unlabelled."""
    score: float
    """Confidence of the class."""
    n_gaussians: int
    centroid: list[float]
    bbox_min: list[float]
    bbox_max: list[float]
    n_views: int
    """Visibility: the number of views in which the object covers at least one pixel."""
