"""Size rules: the constants that follow the number of views, pixels and Gaussians of a run.

The stage configs hold each value *at the reference size* (:data:`REFERENCE`: the 40-view
320x240 synthetic benchmark scene, ~120k Gaussians, on which the presets were tuned). A run
turns them into the values for its own size with :func:`resolve` once the sizes are known
(views and pixels after the capture is planned, Gaussians after reconstruction); at the
reference size every rule gives exactly the preset's value. Each rule is a function below whose
docstring states it and why; README ("Working resolution and keyframes") has the table.

Values given explicitly (job options, CLI flags) are kept: :func:`dcseg.options.build_config`
lists them in :attr:`SizeRules.fixed`. Resolved values join ``fixed`` too, so resolving twice
changes nothing and a stored ``run.json`` config re-runs as it ran.

Constants that are **not** scaled, and why: HDBSCAN ``cluster_selection_epsilon`` and
``min_similarity`` (feature space), the outlier radius and the contact radius (multiples of the
measured Gaussian spacing), ``min_component_fraction`` (relative to the cluster),
``MaskConfig.min_area_fraction`` (a fraction of the image already), affinity ``rays`` (they
sample a view's masks, whose number does not grow with resolution; the loss is quadratic in
them), ``knn_k``/``neighbours`` (nearest neighbours adapt to density), ``min_scale_points``
(a sample size for one mask's 3D scale, not an area), and the small absolute Gaussian counts
(``min_component_size`` 3, ``min_contacts`` 5, ``min_instance_gaussians`` 20), which are floors
against specks: an object's Gaussian count grows with resolution, so they only get safer.

This module must never import torch: the HTTP service imports the configs.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

from dcseg.affinity.config import AffinityConfig
from dcseg.assign.config import AssignConfig
from dcseg.cluster.config import ClusterConfig
from dcseg.reconstruct.config import ReconstructConfig

if TYPE_CHECKING:
    from dcseg.config import PipelineConfig


@dataclass(frozen=True)
class SceneSize:
    """The sizes the rules read.

    Attributes:
        views: frames the run trains on (keyframes at the working resolution).
        pixels: width x height of the working resolution.
        gaussians: Gaussians of the scene; None before reconstruction (the rules that need it
            wait).
    """

    views: int
    pixels: int
    gaussians: int | None = None


REFERENCE_GAUSSIANS = 120_000
REFERENCE = SceneSize(views=40, pixels=320 * 240, gaussians=REFERENCE_GAUSSIANS)
"""The 40-view 320x240 synthetic benchmark scene (``dcseg synth`` defaults; the fast preset
reconstructs it to its 120k-Gaussian cap), on which the presets were tuned."""

STEP_SCHEDULE = (
    "sh_degree_interval",
    "full_res_from",
    "densify_from",
    "densify_until",
    "opacity_reset_every",
)
"""Reconstruction fields counted in steps: they stretch with ``iterations``."""

SCALED: tuple[str, ...] = (
    "reconstruct.iterations",
    *(f"reconstruct.{name}" for name in STEP_SCHEDULE),
    "reconstruct.max_init_points",
    "reconstruct.max_gaussians",
    "affinity.iterations",
    "cluster.min_cluster_size",
    "assign.min_area",
)
"""Every field a size rule sets, as ``stage.field``."""


@dataclass(frozen=True)
class SizeRules:
    """Whether and how far the size rules move the presets' values.

    Attributes:
        enabled: apply the rules; False = the stage configs' values at any size.
        fixed: ``stage.field`` names (of :data:`SCALED`) kept as they are: given explicitly,
            or already resolved for this run.
        reconstruct_max_iterations: reconstruction steps grow with the training views up to
            this (never below the preset's own value).
        affinity_max_iterations: affinity steps grow with the views up to this.
        max_gaussian_growth: ``max_init_points`` and ``max_gaussians`` grow with the training
            pixels up to this factor.
    """

    enabled: bool = True
    fixed: tuple[str, ...] = ()
    reconstruct_max_iterations: int = 7500
    affinity_max_iterations: int = 5000
    max_gaussian_growth: float = 4.0

    def __post_init__(self) -> None:
        unknown = sorted(set(self.fixed) - set(SCALED))
        if unknown:
            raise ValueError(f"fixed names fields no rule sets: {', '.join(unknown)}")
        if self.reconstruct_max_iterations < 0 or self.affinity_max_iterations < 0:
            raise ValueError("the iteration caps must be >= 0")
        if self.max_gaussian_growth < 1.0:
            raise ValueError(f"max_gaussian_growth must be >= 1, got {self.max_gaussian_growth}")

    def follows(self, name: str) -> bool:
        """Does the rule of ``stage.field`` ``name`` set it?"""
        return self.enabled and name not in self.fixed


RULE_PRESETS: dict[str, SizeRules] = {
    "fast": SizeRules(
        reconstruct_max_iterations=1500, affinity_max_iterations=2000, max_gaussian_growth=1.5
    ),
    "paper": SizeRules(reconstruct_max_iterations=30_000, affinity_max_iterations=30_000),
}
"""The rules of each preset. ``fast`` is bounded in time rather than in visits per view: a
reconstruction step at the fast budget's 640 px costs ~4x a step at the reference's 320x240 (it
renders 4x the pixels), so 1500 steps already take most of the 20 minutes a 200-frame 640x480
capture may take; its reconstruction steps therefore stay at 1500 (every training view is still
visited ~8 times at 175 training views, and depth initialisation places the surfaces), its
Gaussian caps grow at most 1.5x and affinity steps (cheap: a sample of rays per step) up to
2000. ``paper``: 30k reconstruction steps at any size, as 3D Gaussian Splatting runs them (857
visits per training view at the reference, still 34 at the budget's 1000 keyframes); affinity
steps grow from 10k up to 30k (from 120 views on); Gaussian caps up to 4x."""


def train_views(views: int, holdout: int) -> int:
    """Frames reconstruction trains on: every ``holdout``-th one is held out
    (:func:`dcseg.reconstruct.views.split_frames`)."""
    if holdout == 0 or views < 2:
        return views
    return views - math.ceil(views / holdout)


def grown_steps(base: int, size: int, reference: int, cap: int) -> int:
    """``base`` steps at ``reference`` items, ``base * size / reference`` at ``size``, between
    ``base`` and ``max(base, cap)``.

    Rule of both training loops, which draw one view per step: every view keeps the number of
    visits it gets at the reference size (fast reconstruction 1500 / 35 = 43 per training
    view, fast affinity 1000 / 40 = 25), so a larger capture is not trained more thinly. Never
    fewer steps than the preset (a small capture is cheap anyway), never more than the cap.
    """
    if reference <= 0:
        return base
    return max(base, min(cap, round(base * size / reference)))


def gaussian_growth(size: SceneSize, holdout: int, cap: float) -> float:
    """The factor of the Gaussian caps: training pixels over the reference's, in ``[1, cap]``.

    Rule: the Gaussians a scene needs grow with the surface detail its training frames show,
    which is the training views (more keyframes, more of the scene) times the pixels per view
    (more detail). The reference's 120k Gaussians for 35 x 320 x 240 training pixels are the
    fast preset's cap; below the reference the preset's cap stays, above it grows up to ``cap``
    times (reconstruction time grows with the Gaussians).
    """
    seen = train_views(size.views, holdout) * size.pixels
    reference = train_views(REFERENCE.views, holdout) * REFERENCE.pixels
    return min(cap, max(1.0, seen / reference))


def sample_size(n: int, cfg: ClusterConfig) -> int:
    """Gaussians HDBSCAN is fitted on (:func:`dcseg.cluster.features.sample_indices`): the
    ``sample_fraction`` of ``n`` between ``min_sample_size`` and ``max_sample_size``."""
    size = round(cfg.sample_fraction * n)
    return max(min(n, cfg.min_sample_size), min(size, n, cfg.max_sample_size))


def min_cluster_size(cfg: ClusterConfig, gaussians: int) -> int:
    """``min_cluster_size`` for the sample of ``gaussians``: in proportion to the sample size.

    Rule: ``min_cluster_size`` counts *sample* points. 7 was tuned on the reference's 10 000-
    point sample; the same value on a larger sample would accept clusters of half the share of
    the scene (and a denser HDBSCAN core distance). In proportion to the sample, the smallest
    cluster stays 0.07 % of the Gaussians and a larger sample finds the clusters the tuned one
    did. The sample is 10 000 up to 500k Gaussians (the 2 % rule's floor), so this only moves
    beyond; never below the config's value.
    """
    now, then = sample_size(gaussians, cfg), sample_size(REFERENCE_GAUSSIANS, cfg)
    return max(cfg.min_cluster_size, round(cfg.min_cluster_size * now / max(then, 1)))


def min_area(cfg: AssignConfig, pixels: int) -> int:
    """Smallest counted class-mask component: in proportion to the view's pixels.

    Rule: an area threshold means a share of the image: 1000 px at 320x240 is 1.3 % of it, at
    any resolution (only ``replicas="components"`` reads it).
    """
    return round(cfg.min_area * pixels / REFERENCE.pixels)


def _reconstruct(cfg: ReconstructConfig, rules: SizeRules, size: SceneSize) -> dict[str, Any]:
    """The reconstruction fields whose rules apply, at ``size``."""
    values: dict[str, Any] = {}
    if rules.follows("reconstruct.iterations"):
        views = train_views(size.views, cfg.holdout)
        reference = train_views(REFERENCE.views, cfg.holdout)
        steps = grown_steps(cfg.iterations, views, reference, rules.reconstruct_max_iterations)
        values["iterations"] = steps
        stretch = steps / cfg.iterations if cfg.iterations else 1.0
        for name in STEP_SCHEDULE:
            value = getattr(cfg, name)
            if rules.follows(f"reconstruct.{name}"):
                values[name] = None if value is None else round(value * stretch)
    growth = gaussian_growth(size, cfg.holdout, rules.max_gaussian_growth)
    for name in ("max_init_points", "max_gaussians"):
        if rules.follows(f"reconstruct.{name}"):
            values[name] = round(getattr(cfg, name) * growth)
    return values


def _affinity(cfg: AffinityConfig, rules: SizeRules, size: SceneSize) -> dict[str, Any]:
    if not rules.follows("affinity.iterations"):
        return {}
    cap = rules.affinity_max_iterations
    return {"iterations": grown_steps(cfg.iterations, size.views, REFERENCE.views, cap)}


def _cluster(cfg: ClusterConfig, rules: SizeRules, size: SceneSize) -> dict[str, Any]:
    if size.gaussians is None or not rules.follows("cluster.min_cluster_size"):
        return {}
    return {"min_cluster_size": min_cluster_size(cfg, size.gaussians)}


def _assign(cfg: AssignConfig, rules: SizeRules, size: SceneSize) -> dict[str, Any]:
    if not rules.follows("assign.min_area"):
        return {}
    return {"min_area": min_area(cfg, size.pixels)}


def resolve_reconstruct(
    cfg: ReconstructConfig, rules: SizeRules, size: SceneSize
) -> tuple[ReconstructConfig, SizeRules]:
    """The reconstruction config at ``size``, and the rules with its resolved fields fixed."""
    values = _reconstruct(cfg, rules, size)
    names = tuple(f"reconstruct.{name}" for name in values)
    return replace(cfg, **values), replace(rules, fixed=(*rules.fixed, *names))


def resolve(cfg: PipelineConfig, size: SceneSize) -> PipelineConfig:
    """Every rule whose sizes are known applied to ``cfg`` (see the module docstring).

    Example:
        >>> from dcseg.config import preset
        >>> big = resolve(preset("fast"), SceneSize(views=400, pixels=320 * 240))
        >>> big.affinity.iterations, big.reconstruct.iterations, big.reconstruct.max_gaussians
        (5000, 7500, 480000)
        >>> resolve(preset("fast"), REFERENCE).reconstruct == preset("fast").reconstruct
        True
    """
    rules = cfg.rules
    changes: dict[str, Any] = {}
    names: list[str] = []
    stages: dict[str, Callable[[Any, SizeRules, SceneSize], dict[str, Any]]] = {
        "affinity": _affinity,
        "cluster": _cluster,
        "assign": _assign,
    }
    for stage, rule in stages.items():
        values = rule(getattr(cfg, stage), rules, size)
        if values:
            changes[stage] = replace(getattr(cfg, stage), **values)
            names += [f"{stage}.{name}" for name in values]
    reconstruct, rules = resolve_reconstruct(cfg.reconstruct, rules, size)
    rules = replace(rules, fixed=(*rules.fixed, *names))
    return replace(cfg, **changes, reconstruct=reconstruct, rules=rules)


def describe(before: PipelineConfig, after: PipelineConfig, size: SceneSize) -> dict[str, Any]:
    """The ``size_rules`` record of ``run.json``: sizes, and each resolved field's preset value
    and value (``explicit`` lists the fields given explicitly, which no rule moved)."""
    return {
        "size": _size_dict(size),
        "reference": _size_dict(REFERENCE),
        "enabled": before.rules.enabled,
        "explicit": list(before.rules.fixed),
        "values": changed(before, after),
    }


def changed(before: PipelineConfig, after: PipelineConfig) -> dict[str, dict[str, Any]]:
    """``{"stage.field": {"preset": v0, "value": v1}}`` of the fields resolved between two
    pipeline configs ``before`` and ``after``."""
    resolved = [n for n in after.rules.fixed if n not in before.rules.fixed]
    return {n: {"preset": _get(before, n), "value": _get(after, n)} for n in resolved}


def reconstruct_record(
    before: ReconstructConfig, rules: SizeRules, size: SceneSize
) -> tuple[ReconstructConfig, dict[str, Any]]:
    """:func:`resolve_reconstruct` and its ``size_rules`` record (``reconstruction.json``)."""
    after, resolved = resolve_reconstruct(before, rules, size)
    values = {
        name: {"preset": _get_stage(before, name), "value": _get_stage(after, name)}
        for name in resolved.fixed
        if name not in rules.fixed
    }
    record = {
        "size": _size_dict(size),
        "reference": _size_dict(REFERENCE),
        "enabled": rules.enabled,
        "explicit": list(rules.fixed),
        "values": values,
    }
    return after, record


def _get(cfg: Any, name: str) -> Any:
    stage, field = name.split(".")
    return getattr(getattr(cfg, stage), field)


def _get_stage(cfg: Any, name: str) -> Any:
    return getattr(cfg, name.split(".")[1])


def _size_dict(size: SceneSize) -> dict[str, Any]:
    return {"views": size.views, "pixels": size.pixels, "gaussians": size.gaussians}


def summary(record: dict[str, Any]) -> str:
    """One line for the terminal: the sizes and every value a rule moved from its preset."""
    size = record["size"]
    scene = f"{size['views']} views of {size['pixels']} px"
    if size.get("gaussians") is not None:
        scene += f", {size['gaussians']} Gaussians"
    moved = [
        f"{name} {v['preset']} -> {v['value']}"
        for name, v in record["values"].items()
        if v["preset"] != v["value"]
    ]
    return f"size rules at {scene}: " + ("; ".join(moved) if moved else "the presets' values")
