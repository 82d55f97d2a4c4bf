"""The one config builder: typed, bounded job options -> :class:`PipelineConfig` + capture options.

The CLI, the HTTP service (``POST /v1/jobs`` validates the body with :class:`JobOptions`) and the
worker (which rebuilds the configs from the stored options) all go through :func:`build_config`,
so a value the API accepts is exactly a value the worker runs, and an absurd one is refused with
a message naming its field before anything is queued.

Every field a job may set is declared once, with its bounds and help, in its config dataclass
(:func:`dcseg.fields.option`); the models here are generated from those declarations
(:mod:`dcseg.option_models`). Bounds are policy, not physics: they keep one job from asking for
days of work or hundreds of gigabytes (``{"affinity": {"iterations": 10**9}}``,
``{"capture": {"size": [60000, 60000]}}``) while staying well above every preset. Non-finite
numbers (``NaN``, ``Infinity``) are refused everywhere.

This module must never import torch: the HTTP service imports it.
"""

from __future__ import annotations

import dataclasses
import typing
from collections.abc import Mapping
from typing import Any, Literal

from pydantic import BaseModel, Field, ValidationError

from dcseg.affinity.config import AffinityConfig
from dcseg.assign.config import AssignConfig
from dcseg.cluster.config import ClusterConfig
from dcseg.config import (
    RENAMED_KEYS,
    CaptureOptions,
    FrameBudget,
    JobConfig,
    PipelineConfig,
    preset,
    renamed,
)
from dcseg.errors import InputError, Problem
from dcseg.option_models import Member, Strict, grouped, settable, values_model
from dcseg.reconstruct.config import ReconstructConfig
from dcseg.segment.config import MaskConfig
from dcseg.sizes import SCALED

PresetName = Literal["fast", "paper"]
"""Named parameter sets (:func:`dcseg.config.preset`)."""
PRESET_NAMES: tuple[str, ...] = typing.get_args(PresetName)

SEGMENT_SECTIONS: dict[str, type[Any]] = {
    "": PipelineConfig,
    "cluster": ClusterConfig,
    "masks": MaskConfig,
    "assign": AssignConfig,
}
"""Where ``segment`` options live: ``PipelineConfig`` itself and its segmentation stages."""

SEGMENT_OPTIONS: dict[str, Member] = grouped("segment", SEGMENT_SECTIONS.values())
"""The ``segment`` options: the fields declared with ``group="segment"``, by name."""

ReconstructOptions = values_model(
    "ReconstructOptions",
    "Overrides of the preset's ``ReconstructConfig`` (unset = the preset's).",
    settable(ReconstructConfig),
    overrides=True,
)
AffinityOptions = values_model(
    "AffinityOptions",
    "Overrides of the preset's ``AffinityConfig`` (unset = the preset's).",
    settable(AffinityConfig),
    overrides=True,
)
CaptureOptionsIn = values_model(
    "CaptureOptionsIn",
    "How the capture is read: the fields of :class:`dcseg.config.CaptureOptions`.",
    settable(CaptureOptions),
    overrides=False,
)
BudgetOptionsIn = values_model(
    "BudgetOptionsIn",
    "Overrides of the preset's :class:`dcseg.config.FrameBudget` (unset = the preset's).",
    settable(FrameBudget),
    overrides=True,
    nullable=True,
)
SegmentOptionsIn = values_model(
    "SegmentOptionsIn",
    "Segmentation parameters: clustering scale, matcher, label maps and the seed of every\n"
    "    stage.",
    SEGMENT_OPTIONS,
    overrides=False,
)


class JobOptions(Strict):
    """Method parameters of one job (stored with it as ``config.options``)."""

    capture: CaptureOptionsIn = Field(default_factory=CaptureOptionsIn)  # type: ignore[valid-type]
    """How the capture is read (frame stride, size, depth truncation, intrinsics)."""

    reconstruct: ReconstructOptions = Field(default_factory=ReconstructOptions)  # type: ignore[valid-type]
    """Overrides of the reconstruction preset (e.g. ``{"iterations": 500}``), each bounded."""

    affinity: AffinityOptions = Field(default_factory=AffinityOptions)  # type: ignore[valid-type]
    """Overrides of the affinity-training preset (e.g. ``{"iterations": 500}``), each bounded."""

    segment: SegmentOptionsIn = Field(default_factory=SegmentOptionsIn)  # type: ignore[valid-type]
    """Clustering scale, matcher and seed of the segmentation stages."""

    budget: BudgetOptionsIn = Field(default_factory=BudgetOptionsIn)  # type: ignore[valid-type]
    """Working resolution and keyframe budget (e.g. ``{"max_side": "native"}``), each bounded."""

    def stored(self) -> dict[str, Any]:
        """The JSON form kept with a job; overrides hold only the fields that were given."""
        data = self.model_dump(mode="json")
        for name in ("reconstruct", "affinity", "budget"):
            data[name] = getattr(self, name).model_dump(mode="json", exclude_unset=True)
        return data


def build_config(preset_name: str | PipelineConfig, options: JobOptions) -> JobConfig:
    """The typed config of a job; InputError names every bad field.

    The preset gives every value; ``options`` override single fields; ``segment.seed`` seeds
    every stage. A stored run's config may stand for the preset (re-segmenting a run: only
    the options given change it). A field given here is kept at any scene size: it joins
    ``rules.fixed``, so no size rule (:mod:`dcseg.sizes`) moves it. Cross-field rules of the
    stage configs (``knn_sample <= knn_k``, ...) are checked here too, so the API refuses what
    the worker would.
    """
    base = _base(preset_name)
    stored = isinstance(preset_name, PipelineConfig)
    seg = group(options, "segment").model_dump(exclude_unset=stored)
    reconstruct = _replace(base.reconstruct, options.reconstruct, "options.reconstruct")
    affinity = _replace(base.affinity, options.affinity, "options.affinity")
    try:
        cfg = dataclasses.replace(
            _segment(base, seg),
            reconstruct=reconstruct,
            affinity=affinity,
            budget=_budget(base.budget, options.budget),
            rules=dataclasses.replace(
                base.rules, fixed=tuple(dict.fromkeys((*base.rules.fixed, *_explicit(options))))
            ),
        )
        cfg = cfg.seeded(seg["seed"]) if "seed" in seg else cfg
    except ValueError as error:
        raise InputError([Problem("options", str(error))]) from None
    try:
        capture = CaptureOptions(**group(options, "capture").model_dump())
    except ValueError as error:
        raise InputError([Problem("options.capture", str(error))]) from None
    return JobConfig(cfg, capture)


def _segment(base: PipelineConfig, given: dict[str, Any]) -> PipelineConfig:
    """``base`` with the given ``segment`` options set in the sections that declare them."""
    changes: dict[str, Any] = {}
    for section, cls in SEGMENT_SECTIONS.items():
        names = [n for n, (c, _) in SEGMENT_OPTIONS.items() if c is cls and n in given]
        values = {n: given[n] for n in names if n != "seed"}  # the seed goes to every stage
        if values and section:
            changes[section] = dataclasses.replace(getattr(base, section), **values)
        elif values:
            changes.update(values)
    return dataclasses.replace(base, **changes)


def _base(preset_name: str | PipelineConfig) -> PipelineConfig:
    if isinstance(preset_name, PipelineConfig):
        return preset_name
    if preset_name not in PRESET_NAMES:
        known = ", ".join(PRESET_NAMES)
        raise InputError([Problem("preset", f"unknown preset {preset_name!r} (known: {known})")])
    return preset(preset_name)


def group(options: JobOptions, name: str) -> BaseModel:
    """The option group ``name`` of ``options`` (its model is generated, so typed here)."""
    model: BaseModel = getattr(options, name)
    return model


def _explicit(options: JobOptions) -> tuple[str, ...]:
    """The given fields that a size rule would otherwise set, as ``stage.field``."""
    given = [
        f"{stage}.{name}"
        for stage in ("reconstruct", "affinity")
        for name in getattr(options, stage).model_dump(exclude_unset=True)
    ]
    return tuple(name for name in SCALED if name in given)


def _budget(base: FrameBudget, given: BaseModel) -> FrameBudget:
    """The preset's budget with the given fields; ``"native"``/``"all"`` lift a cap."""
    changes: dict[str, Any] = {}
    for name, value in given.model_dump(exclude_unset=True).items():
        if value is not None:
            changes[name] = None if value in ("native", "all") else value
    return dataclasses.replace(base, **changes)


def _replace(base: Any, overrides: BaseModel, where: str) -> Any:
    try:
        return dataclasses.replace(base, **overrides.model_dump(exclude_unset=True))
    except ValueError as error:
        raise InputError([Problem(where, str(error))]) from None


def parse_options(data: Mapping[str, Any] | None) -> JobOptions:
    """Stored or submitted options (JSON) as :class:`JobOptions`; InputError names each field."""
    try:
        return JobOptions.model_validate(dict(data or {}))
    except ValidationError as error:
        raise InputError(_problems(error)) from None


def from_stored(config: Mapping[str, Any]) -> JobConfig:
    """The config of a stored job config ``{"preset": ..., "options": {...}}``."""
    options = parse_options(renamed(config.get("options") or {}, RENAMED_KEYS))
    return build_config(str(config.get("preset", "fast")), options)


def _problems(error: ValidationError) -> list[Problem]:
    problems = []
    for item in error.errors():
        where = ".".join(["options", *(str(p) for p in item["loc"])])
        problems.append(Problem(where, str(item["msg"])))
    return problems


def check_size(options: JobOptions, native: tuple[int, int] | None, where: str) -> None:
    """Refuse a target size above the capture's native ``(width, height)`` (no upscaling)."""
    size = group(options, "capture").model_dump()["size"]
    if size is None or native is None:
        return
    if size[0] > native[0] or size[1] > native[1]:
        reason = (
            f"size {size[0]}x{size[1]} is larger than the capture's {native[0]}x{native[1]}; "
            "frames are only ever downscaled"
        )
        raise InputError([Problem(where, reason)])
