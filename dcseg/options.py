"""The one config builder: typed, bounded job options -> :class:`PipelineConfig` + capture options.

The CLI, the HTTP service (``POST /v1/jobs`` validates the body with :class:`JobOptions`) and the
worker (which rebuilds the configs from the stored options) all go through :func:`build_config`,
so a value the API accepts is exactly a value the worker runs, and an absurd one is refused with
a message naming its field before anything is queued.

Bounds are policy, not physics: they keep one job from asking for days of work or hundreds of
gigabytes (``{"affinity": {"iterations": 10**9}}``, ``{"capture": {"size": [60000, 60000]}}``)
while staying well above every preset (:data:`RECONSTRUCT_BOUNDS`, :data:`AFFINITY_BOUNDS`).
Non-finite numbers (``NaN``, ``Infinity``) are refused everywhere.

This module must never import torch: the HTTP service imports it.
"""

from __future__ import annotations

import dataclasses
import typing
from collections.abc import Mapping
from typing import Annotated, Any, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    PlainValidator,
    StrictBool,
    ValidationError,
    WithJsonSchema,
    create_model,
)

from dcseg.affinity.config import AffinityConfig
from dcseg.config import (
    DEFAULT_SCALE,
    CaptureOptions,
    FrameBudget,
    JobConfig,
    PipelineConfig,
    preset,
)
from dcseg.errors import InputError, Problem
from dcseg.reconstruct.config import ReconstructConfig
from dcseg.sizes import SCALED

PresetName = Literal["fast", "paper"]
"""Named parameter sets (:func:`dcseg.config.preset`)."""
PRESET_NAMES: tuple[str, ...] = typing.get_args(PresetName)

MAX_SIDE = 8192
"""Largest width or height a job may resample its frames to (pixels); never above the capture's
own resolution either (no upscaling, checked where the capture's size is known)."""

MAX_SEED = 2**31 - 1

Bounds = dict[str, tuple[float, float]]
"""Closed ``[low, high]`` range of each numeric field a job may override."""

RECONSTRUCT_BOUNDS: Bounds = {
    "iterations": (0, 100_000),
    "sh_degree": (0, 3),
    "sh_degree_interval": (1, 100_000),
    "holdout": (0, 1000),
    "train_downscale": (1, 16),
    "full_res_from": (0, 100_000),
    "full_res_crop": (0.05, 1.0),
    "depth_filter_window": (1, 15),
    "depth_filter_k": (0.1, 100.0),
    "pose_lr": (0.0, 0.1),
    "pose_from": (0, 100_000),
    "pose_align_steps": (0, 10_000),
    "pose_align_lr": (1e-6, 0.1),
    "init_pixel_stride": (1, 64),
    "voxel_size": (1e-4, 1.0),
    "voxel_fraction": (1e-5, 0.1),
    "voxel_min": (1e-4, 1.0),
    "voxel_max": (1e-4, 1.0),
    "max_init_points": (1, 5_000_000),
    "init_opacity": (1e-4, 0.9999),
    "init_thickness": (1e-3, 1.0),
    "thickness_weight": (0.0, 1000.0),
    "centre_weight": (0.0, 1000.0),
    "centre_band": (0.0, 100.0),
    "ssim_lambda": (0.0, 1.0),
    "depth_weight": (0.0, 100.0),
    "means_lr_init": (0.0, 1.0),
    "means_lr_final": (0.0, 1.0),
    "sh_dc_lr": (0.0, 1.0),
    "sh_rest_lr": (0.0, 1.0),
    "opacity_lr": (0.0, 1.0),
    "scales_lr": (0.0, 1.0),
    "quats_lr": (0.0, 1.0),
    "densify_from": (0, 100_000),
    "densify_until": (0, 100_000),
    "densify_every": (1, 100_000),
    "grad_threshold": (0.0, 1.0),
    "clone_scale_fraction": (0.0, 1.0),
    "prune_opacity": (0.0, 1.0),
    "prune_scale_fraction": (0.0, 10.0),
    "opacity_reset_every": (0, 100_000),
    "max_gaussians": (1, 10_000_000),
}
"""Bounds of the reconstruction overrides (the paper preset runs 30k steps, 1M Gaussians)."""

AFFINITY_BOUNDS: Bounds = {
    "feature_dim": (1, 256),
    "iterations": (0, 100_000),
    "rays": (1, 100_000),
    "random_scales": (0, 256),
    "lr": (1e-8, 1.0),
    "adam_eps": (1e-20, 1.0),
    "init_std": (1e-8, 10.0),
    "knn_k": (1, 128),
    "knn_sample": (1, 128),
    "pos_threshold": (-1.0, 1.0),
    "neg_threshold": (-1.0, 1.0),
    "max_pair_weight": (1.0, 1000.0),
    "norm_weight": (0.0, 100.0),
    "n_quantiles": (1, 100_000),
    "min_scale_points": (2, 1_000_000),
}
"""Bounds of the affinity-training overrides (the paper preset runs 10k steps, 1000 rays)."""

RECONSTRUCT_CHOICES: dict[str, tuple[str, ...]] = {"backend": ("cpu", "reference", "gsplat")}
"""String fields a job may override, with their allowed values."""

NOT_OVERRIDABLE = ("seed",)
"""Set once for every stage by ``segment.seed``."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


def _field_type(
    name: str, hint: Any, bounds: Bounds, choices: Mapping[str, tuple[str, ...]]
) -> Any:
    """The pydantic type of one overridable dataclass field (bounded, finite)."""
    args = typing.get_args(hint)
    optional = type(None) in args
    base = next((a for a in args if a is not type(None)), hint) if args else hint
    if name in choices:
        inner: Any = Literal[choices[name]]  # type: ignore[valid-type]
    elif base is bool:
        inner = StrictBool
    elif base in (int, float):
        low, high = bounds[name]
        kind: Any = int if base is int else float
        inner = Annotated[kind, Field(ge=low, le=high, allow_inf_nan=False)]
    else:  # pragma: no cover - guarded by the tests over every field
        raise TypeError(f"no option type for {name}: {hint}")
    return inner | None if optional else inner


def _overrides_model(
    name: str, stage: type[Any], bounds: Bounds, choices: Mapping[str, tuple[str, ...]]
) -> type[_Strict]:
    """A model of ``stage``'s overridable fields, all optional (unset = the preset's value)."""
    hints = typing.get_type_hints(stage)
    fields: dict[str, Any] = {}
    for f in dataclasses.fields(stage):
        if f.name in NOT_OVERRIDABLE:
            continue
        doc = f"bounds {list(bounds[f.name])}" if f.name in bounds else None
        fields[f.name] = (
            _field_type(f.name, hints[f.name], bounds, choices),
            Field(default=None, description=doc),
        )
    model: type[_Strict] = create_model(name, __base__=_Strict, **fields)
    model.__doc__ = f"Overrides of the preset's ``{stage.__name__}`` (unset = the preset's)."
    return model


ReconstructOptions = _overrides_model(
    "ReconstructOptions", ReconstructConfig, RECONSTRUCT_BOUNDS, RECONSTRUCT_CHOICES
)
AffinityOptions = _overrides_model("AffinityOptions", AffinityConfig, AFFINITY_BOUNDS, {})

Side = Annotated[int, Field(ge=1, le=MAX_SIDE)]
Finite = Annotated[float, Field(allow_inf_nan=False)]


class CaptureOptionsIn(_Strict):
    """How the capture is read: the fields of :class:`dcseg.config.CaptureOptions`."""

    stride: int = Field(default=1, ge=1, le=10_000, description="keep every stride-th frame")
    max_frames: int | None = Field(
        default=None, ge=1, le=100_000, description="keep at most this many"
    )
    size: tuple[Side, Side] | None = Field(
        default=None, description=f"resample frames to (width, height), at most {MAX_SIDE}"
    )
    depth_trunc: float | None = Field(
        default=None, gt=0, le=1000, description="ignore depth beyond (m)"
    )
    intrinsics: tuple[Finite, Finite, Finite, Finite] | None = Field(
        default=None, description="(fx, fy, cx, cy) for layouts that store none"
    )
    min_confidence: int = Field(
        default=0,
        ge=0,
        le=2,
        description="Record3D/Polycam: drop depth below this ARKit confidence (0 low, 1 medium, "
        "2 high; 0 = keep all)",
    )


MAX_KEYFRAMES = 100_000
"""Most keyframes a job may train on."""

MIN_WORKING_SIDE = 16
"""Smallest working resolution (longer side, pixels) a job may ask for."""


def _cap(low: int, high: int, word: str) -> Any:
    """An ``int`` in ``[low, high]`` or the word ``word`` (no cap), with one precise error."""

    def check(value: Any) -> int | str | None:
        if value is None or value == word:
            return value  # type: ignore[no-any-return]
        if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
            raise ValueError(f"must be an integer in [{low}, {high}] or {word!r}, got {value!r}")
        return value

    schema = {
        "anyOf": [
            {"type": "integer", "minimum": low, "maximum": high},
            {"const": word},
            {"type": "null"},
        ]
    }
    return Annotated[int | str | None, PlainValidator(check), WithJsonSchema(schema)]


class BudgetOptionsIn(_Strict):
    """Overrides of the preset's :class:`dcseg.config.FrameBudget` (unset = the preset's)."""

    max_side: _cap(MIN_WORKING_SIDE, MAX_SIDE, "native") = Field(  # type: ignore[valid-type]
        default=None,
        description="downscale by an integer factor until the longer side is at most this "
        f"(pixels, {MIN_WORKING_SIDE}-{MAX_SIDE}); 'native' = no downscaling",
    )
    max_frames: _cap(1, MAX_KEYFRAMES, "all") = Field(  # type: ignore[valid-type]
        default=None, description=f"at most this many keyframes (1-{MAX_KEYFRAMES}); 'all' = no cap"
    )
    min_translation: float | None = Field(
        default=None, ge=0.0, le=100.0, description="keyframe when the camera moved this far (m)"
    )
    min_rotation_deg: float | None = Field(
        default=None, ge=0.0, le=180.0, description="... or turned this many degrees"
    )


class SegmentOptionsIn(_Strict):
    """Segmentation parameters: clustering scale, matcher, label maps and the seed of every
    stage."""

    scale: float = Field(
        default=DEFAULT_SCALE, ge=0.0, le=1.0, description="clustering scale in [0, 1]"
    )
    matcher: Literal["assignment", "matching"] = Field(
        default="assignment", description="class replication (assignment) or one-to-one"
    )
    seed: int = Field(default=0, ge=0, le=MAX_SEED, description="seed of every random choice")
    label_maps: Literal["gaussians", "clusters"] = Field(
        default="gaussians",
        description="rendered label maps from the Gaussians' final classes (gaussians, as in the "
        "labelled PLY) or from the cluster maps through each cluster's class (clusters)",
    )


class JobOptions(_Strict):
    """Method parameters of one job (stored with it as ``config.options``)."""

    capture: CaptureOptionsIn = Field(default_factory=CaptureOptionsIn)
    """How the capture is read (frame stride, size, depth truncation, intrinsics)."""

    reconstruct: ReconstructOptions = Field(default_factory=ReconstructOptions)  # type: ignore[valid-type]
    """Overrides of the reconstruction preset (e.g. ``{"iterations": 500}``), each bounded."""

    affinity: AffinityOptions = Field(default_factory=AffinityOptions)  # type: ignore[valid-type]
    """Overrides of the affinity-training preset (e.g. ``{"iterations": 500}``), each bounded."""

    segment: SegmentOptionsIn = Field(default_factory=SegmentOptionsIn)
    """Clustering scale, matcher and seed of the segmentation stages."""

    budget: BudgetOptionsIn = Field(default_factory=BudgetOptionsIn)
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
    seg = options.segment.model_dump(exclude_unset=stored)
    reconstruct = _replace(base.reconstruct, options.reconstruct, "options.reconstruct")
    affinity = _replace(base.affinity, options.affinity, "options.affinity")
    assign = {"mode": seg.get("matcher"), "maps_from": seg.get("label_maps")}
    try:
        cfg = dataclasses.replace(
            base,
            reconstruct=reconstruct,
            affinity=affinity,
            scale=seg.get("scale", base.scale),
            assign=dataclasses.replace(
                base.assign, **{k: v for k, v in assign.items() if v is not None}
            ),
            budget=_budget(base.budget, options.budget),
            rules=dataclasses.replace(
                base.rules, fixed=tuple(dict.fromkeys((*base.rules.fixed, *_explicit(options))))
            ),
        )
        cfg = cfg.seeded(seg["seed"]) if "seed" in seg else cfg
        capture = CaptureOptions(**options.capture.model_dump())
    except ValueError as error:
        raise InputError([Problem("options", str(error))]) from None
    return JobConfig(cfg, capture)


def _base(preset_name: str | PipelineConfig) -> PipelineConfig:
    if isinstance(preset_name, PipelineConfig):
        return preset_name
    if preset_name not in PRESET_NAMES:
        known = ", ".join(PRESET_NAMES)
        raise InputError([Problem("preset", f"unknown preset {preset_name!r} (known: {known})")])
    return preset(preset_name)


def _explicit(options: JobOptions) -> tuple[str, ...]:
    """The given fields that a size rule would otherwise set, as ``stage.field``."""
    given = [
        f"{stage}.{name}"
        for stage in ("reconstruct", "affinity")
        for name in getattr(options, stage).model_dump(exclude_unset=True)
    ]
    return tuple(name for name in SCALED if name in given)


def _budget(base: FrameBudget, given: BudgetOptionsIn) -> FrameBudget:
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
    options = parse_options(config.get("options"))
    return build_config(str(config.get("preset", "fast")), options)


def _problems(error: ValidationError) -> list[Problem]:
    problems = []
    for item in error.errors():
        where = ".".join(["options", *(str(p) for p in item["loc"])])
        problems.append(Problem(where, str(item["msg"])))
    return problems


def check_size(options: JobOptions, native: tuple[int, int] | None, where: str) -> None:
    """Refuse a target size above the capture's native ``(width, height)`` (no upscaling)."""
    size = options.capture.size
    if size is None or native is None:
        return
    if size[0] > native[0] or size[1] > native[1]:
        reason = (
            f"size {size[0]}x{size[1]} is larger than the capture's {native[0]}x{native[1]}; "
            "frames are only ever downscaled"
        )
        raise InputError([Problem(where, reason)])
