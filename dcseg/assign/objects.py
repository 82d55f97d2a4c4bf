"""From labelled clusters to the scene's objects and each Gaussian's final class.

The steps after the votes and their refinement (:mod:`dcseg.assign.refinement`), in order:
unlabelled clusters adopt a touching neighbour's class (:mod:`dcseg.assign.adoption`),
unlabelled Gaussians on labelled surfaces are completed (:mod:`dcseg.assign.completion`),
clusters become object instances and stuff regions (:mod:`dcseg.assign.instances`), and
Gaussians may then follow their own evidence (:func:`~dcseg.assign.consistency.follow_evidence`).
With ``AssignConfig.objects`` off, every cluster is one instance (the paper's output).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from dcseg.assign.adoption import adopt_fragments
from dcseg.assign.agnostic import agnostic_instances
from dcseg.assign.completion import complete_labels
from dcseg.assign.config import AssignConfig
from dcseg.assign.consistency import follow_evidence
from dcseg.assign.instances import Instances, object_instances
from dcseg.assign.stage import Assignment
from dcseg.cluster.features import Clustering


def stuff_ids(class_names: Sequence[str], stuff_classes: Sequence[str]) -> list[int]:
    """Indices of the vocabulary's stuff classes (names absent from it are ignored).

    Example:
        >>> stuff_ids(["wall", "duck", "floor"], ("floor", "wall", "ceiling"))
        [0, 2]
    """
    return [i for i, name in enumerate(class_names) if name in stuff_classes]


def build_objects(
    means: NDArray[np.float64],
    radius: float,
    evidence: NDArray[np.float64] | None,
    clustering: Clustering,
    assignment: Assignment,
    semantic_ids: NDArray[np.int64],
    cfg: AssignConfig,
    stuff: Sequence[int],
    footprints: NDArray[np.float64] | None = None,
    background: NDArray[np.bool_] | None = None,
) -> tuple[Instances, NDArray[np.int64]]:
    """Adopt unlabelled clusters, complete labels, build object instances, and (with
    ``cfg.follow_evidence_ratio``) let Gaussians follow their own evidence.

    ``means`` are the Gaussians' centres and ``radius`` the contact radius
    (:func:`dcseg.cluster.outliers.adaptive_radius`, ``cfg.contact_factor``); ``stuff``
    the vocabulary's stuff classes (:func:`stuff_ids`); ``footprints`` each Gaussian's largest
    scale, across which label completion also reaches (:mod:`dcseg.assign.completion`);
    ``background`` the Gaussians that the class masks leave unlabelled: no class in the end,
    and neither adoption nor completion gives them one (``cfg.background_share``).
    Without evidence, a contact radius, or both ``cfg.objects`` and ``cfg.complete`` off,
    every cluster is one instance and ``semantic_ids`` stay as they are. Without classes (a
    class-agnostic run) and with ``cfg.objects``, touching clusters whose features agree
    merge (:mod:`dcseg.assign.agnostic`).

    Returns:
        The instances and the ``[N]`` final class per Gaussian (-1 = none).
    """
    labels = clustering.labels
    if cfg.objects and assignment.votes.shape[1] == 0:  # no classes: a class-agnostic run
        return agnostic_instances(means, labels, clustering.centers, radius, cfg), semantic_ids
    if (not cfg.objects and not cfg.complete) or radius <= 0 or evidence is None:
        return per_cluster_instances(labels, assignment), semantic_ids
    fragments = adopt_fragments(means, labels, semantic_ids, evidence, radius, cfg, background)
    ids = fragments.semantic if cfg.objects else semantic_ids
    if cfg.complete:
        ids = complete_labels(
            means, ids, evidence, radius=radius, neighbours=cfg.neighbours,
            rounds=cfg.completion_rounds, evidence_weight=cfg.evidence_weight,
            footprints=footprints, background=background,
        )  # fmt: skip
    if not cfg.objects:
        instances = per_cluster_instances(labels, assignment)
    else:
        instances = object_instances(
            means, labels, ids, fragments, clustering.centers, assignment.votes,
            assignment.scores, stuff, radius, cfg,
        )  # fmt: skip
    if cfg.follow_evidence_ratio > 0:  # after the objects: a few moved Gaussians leave theirs
        ids = follow_evidence(ids, evidence, cfg.follow_evidence_ratio)
        instances = instances.of_classes(ids)
    if background is not None and (background & (ids >= 0)).any():
        ids = np.where(background, -1, ids)  # what an object's cluster took of the background
        instances = instances.of_classes(ids)
    return instances, ids


def per_cluster_instances(labels: NDArray[np.int64], assignment: Assignment) -> Instances:
    """One instance per cluster (``AssignConfig.objects`` off: the paper's output): ``labels``
    (``[N]`` cluster per Gaussian) are the instance ids, the clusters' classes and scores
    the instances'."""
    k = len(assignment.labels)
    return Instances(
        labels.copy(), assignment.labels.copy(), assignment.scores.copy(), np.arange(k)
    )
