"""What a segmentation of a trained scene gives: clusters, classes, objects and per-view maps.

:class:`Segmentation` is what :func:`dcseg.pipeline.segment_scene` returns and what the run
writers save (:mod:`dcseg.io.run_output`); :class:`Labels` is the part evaluation needs, which
a finished run's exports also give back.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from dcseg.assign.instances import Instances
from dcseg.assign.stage import Assignment
from dcseg.cluster.features import Clustering


@dataclass(frozen=True)
class Labels:
    """What evaluation needs of a segmentation (also readable back from a run's exports).

    Attributes:
        semantic_ids: ``[N]`` class per Gaussian, -1 = none.
        label_maps: per view name, ``[H, W]`` class per pixel (-1 = none).
        instance_ids: ``[N]`` object instance per Gaussian (0-based, -1 = none); None when
            not known (instance metrics are then left out).
    """

    semantic_ids: NDArray[np.int64]
    label_maps: dict[str, NDArray[np.int32]]
    instance_ids: NDArray[np.int64] | None = None


@dataclass(frozen=True)
class Segmentation:
    """Objects, clusters and classes of a trained scene at one scale with one set of class masks.

    Attributes:
        clustering: cluster per Gaussian (``labels [N]``, -1 = noise): the cluster level.
        assignment: class per cluster (``labels [K]``, -1 = unlabelled) and votes.
        instances: object instance per Gaussian and each object's class and score: the object
            level (:mod:`dcseg.assign.instances`).
        semantic_ids: ``[N]`` class per Gaussian after label completion, -1 = none.
        cluster_maps: per view name, ``[H, W]`` cluster per pixel (-1 = none), cleaned.
        label_maps: per view name, ``[H, W]`` class per pixel (-1 = none): rendered from
            ``semantic_ids`` or from the cluster maps (``AssignConfig.label_maps``).
        mask_agreement: how well the class-aware masks agree with the labelled clusters
            (:func:`~dcseg.assign.consistency.mask_agreement`), NaN when not measured.
        evidence_trusted: whether it reached ``AssignConfig.trust_agreement``, so that the
            Gaussians' own evidence decided the consistency step and completion.
        unanimous: share of the labelled clusters that every matched view names alike
            (``Assignment.unanimous`` of the vote): where the segmenter is wrong about them,
            no vote can tell. NaN when not measured.
        confusions: clusters whose voted class was taken for a consistent confusion and
            replaced (``AssignConfig.confusion_min_share``).
        rings_given_back: Gaussians of objects' support rings given back to their supports
            (``AssignConfig.ring_plane_tol``, :mod:`dcseg.assign.rings`).
        background: Gaussians that the class masks leave unlabelled and that stay without a
            class (``AssignConfig.background_share``).
    """

    clustering: Clustering
    assignment: Assignment
    instances: Instances
    semantic_ids: NDArray[np.int64]
    cluster_maps: dict[str, NDArray[np.int32]]
    label_maps: dict[str, NDArray[np.int32]]
    mask_agreement: float = float("nan")
    evidence_trusted: bool = False
    unanimous: float = float("nan")
    confusions: int = 0
    rings_given_back: int = 0
    background: int = 0

    @property
    def n_clusters(self) -> int:
        return int(self.clustering.centers.shape[0])

    @property
    def n_instances(self) -> int:
        return self.instances.n_instances

    def instance_map(self, name: str) -> NDArray[np.int64]:
        """View ``name``'s ``[H, W]`` object instance per pixel (-1 = none): its cluster map
        through each cluster's object (:attr:`Instances.of_cluster`); built on request, so
        writers hold one view's at a time."""
        table = np.concatenate([[-1], self.instances.of_cluster]).astype(np.int64)
        return table[self.cluster_maps[name] + 1]

    def labels(self) -> Labels:
        return Labels(self.semantic_ids, self.label_maps, self.instances.ids)
