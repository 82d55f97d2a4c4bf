"""Method and reader parameters as plain stdlib dataclasses.

This module must never import torch: the HTTP service imports it to describe job options.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, fields, replace
from typing import Any

from dcseg.affinity.config import PRESETS as AFFINITY_PRESETS
from dcseg.affinity.config import AffinityConfig
from dcseg.assign.config import AssignConfig
from dcseg.cluster.config import ClusterConfig
from dcseg.evaluate.config import EvaluateConfig
from dcseg.fields import option
from dcseg.reconstruct.config import PRESETS as RECONSTRUCT_PRESETS
from dcseg.reconstruct.config import ReconstructConfig
from dcseg.segment.config import MaskConfig
from dcseg.sizes import RULE_PRESETS, SizeRules

MAX_SIDE = 8192
"""Largest width or height a job may resample its frames to (pixels); never above the capture's
own resolution either (no upscaling, checked where the capture's size is known)."""

MAX_KEYFRAMES = 100_000
"""Most keyframes a job may train on."""

MIN_WORKING_SIDE = 16
"""Smallest working resolution (longer side, pixels) a job may ask for."""

MAX_SEED = 2**31 - 1


@dataclass(frozen=True)
class CaptureOptions:
    """Options every capture reader honours.

    Attributes:
        stride: keep every ``stride``-th frame (1 = all).
        max_frames: keep at most this many frames after striding (None = all).
        size: target ``(width, height)``; images are downscaled (area filter), depth is
            resampled with nearest neighbour and intrinsics are scaled to match. None = native.
        depth_trunc: depth beyond this many metres is set to 0 (invalid). None = keep all.
        intrinsics: ``(fx, fy, cx, cy)`` at the native colour resolution, for layouts that do
            not store intrinsics (7-Scenes, Replica without ``cam_params.json``).
        distortion: the lens distortion of ``intrinsics``, OpenCV's ``k1 k2 p1 p2 [k3 [k4 k5
            k6]]`` (4, 5 or 8 numbers; e.g. TUM freiburg1's ``d0..d4``): the frames, and masks
            given for them, are undistorted when read (:mod:`dcseg.lens`). None = pinhole.
        min_confidence: for layouts that store an ARKit depth confidence per pixel (Record3D,
            Polycam; levels 0 = low, 1 = medium, 2 = high), depth whose confidence is below this
            level is set to 0 (invalid). 0 = keep all depth (confidence files are not read).
        sync_tolerance_ms: for layouts that pair colour, depth and poses by timestamp (TUM
            RGB-D, ARKitScenes), the largest time difference accepted, in milliseconds. None =
            the layout's own default (TUM 20 ms, as its ``associate.py``; ARKitScenes 5 ms).
        pose_scale: metres per unit of the capture's poses: camera positions (and COLMAP's
            sparse points) are multiplied by it when listed, before anything else reads them;
            depth maps stay in metres. For a COLMAP model made from images alone (its units
            are arbitrary) whose size the user knows. None = the poses are in metres.
    """

    stride: int = option(1, bounds=(1, 10_000), help="keep every stride-th frame", flag="--stride")
    max_frames: int | None = option(
        None, bounds=(1, 100_000), help="keep at most this many", flag="--max-frames"
    )
    size: tuple[int, int] | None = option(
        None,
        bounds=(1, MAX_SIDE),
        help=f"resample frames to (width, height), at most {MAX_SIDE}",
        flag="--size",
    )
    depth_trunc: float | None = option(
        None, bounds=(0, 1000), above=True, help="ignore depth beyond (m)", flag="--depth-trunc"
    )
    intrinsics: tuple[float, float, float, float] | None = option(
        None, help="(fx, fy, cx, cy) for layouts that store none", flag="--intrinsics"
    )
    distortion: tuple[float, ...] | None = option(
        None,
        help="lens distortion of the intrinsics option, OpenCV's k1,k2,p1,p2[,k3[,k4,k5,k6]]: "
        "frames and masks are undistorted when read (default: none)",
        flag="--distortion",
    )
    min_confidence: int = option(
        0,
        bounds=(0, 2),
        help="Record3D/Polycam: drop depth below this ARKit confidence (0 low, 1 medium, "
        "2 high; 0 = keep all)",
        flag="--min-confidence",
    )
    sync_tolerance_ms: float | None = option(
        None,
        bounds=(0, 1000),
        above=True,
        help="TUM/ARKitScenes: largest time difference (ms) when pairing colour with depth and "
        "poses (default: TUM 20, ARKitScenes 5)",
        flag="--sync-tolerance-ms",
    )
    pose_scale: float | None = option(
        None,
        bounds=(0, 1e6),
        above=True,
        help="metres per unit of the capture's poses (and COLMAP sparse points), e.g. for a "
        "COLMAP model from images alone; depth stays in metres (default: poses in metres)",
        flag="--pose-scale",
    )

    def __post_init__(self) -> None:
        if self.stride < 1:
            raise ValueError(f"stride must be >= 1, got {self.stride}")
        if self.max_frames is not None and self.max_frames < 1:
            raise ValueError(f"max_frames must be >= 1, got {self.max_frames}")
        if self.size is not None and (self.size[0] < 1 or self.size[1] < 1):
            raise ValueError(f"size must be positive, got {self.size}")
        if self.depth_trunc is not None and self.depth_trunc <= 0:
            raise ValueError(f"depth_trunc must be > 0, got {self.depth_trunc}")
        if self.min_confidence not in (0, 1, 2):
            raise ValueError(f"min_confidence must be 0, 1 or 2, got {self.min_confidence}")
        if self.sync_tolerance_ms is not None and not self.sync_tolerance_ms > 0:
            raise ValueError(f"sync_tolerance_ms must be > 0, got {self.sync_tolerance_ms}")
        if self.pose_scale is not None and not 0 < self.pose_scale <= 1e6:
            raise ValueError(f"pose_scale must be in (0, 1e6], got {self.pose_scale}")
        if self.distortion is not None:
            self._check_distortion(self.distortion)

    def _check_distortion(self, distortion: tuple[float, ...]) -> None:
        if self.intrinsics is None:
            raise ValueError("distortion is the lens of intrinsics: give intrinsics too")
        if len(distortion) not in (4, 5, 8):
            raise ValueError(
                f"distortion must be 4, 5 or 8 numbers (k1,k2,p1,p2[,k3[,k4,k5,k6]]), "
                f"got {len(distortion)}"
            )
        if not all(math.isfinite(v) for v in distortion):
            raise ValueError(f"distortion must be finite numbers, got {list(distortion)}")


@dataclass(frozen=True)
class CacheConfig:
    """Truncation of the per-view blending-weight cache (:mod:`dcseg.render.blend_weights`).

    Attributes:
        min_weight: contributions below this blending weight are not stored.
        max_per_pixel: at most this many contributions are stored per pixel (front-most).
        memory_mb: the cache lives in the run's ``state/views/``; at most this many MB of it
            are kept in memory (the views first seen, until it is full; the others are read
            again from disk on each use: :class:`dcseg.io.run_state.BlendMemory`). Changes
            time and memory, never results: a capture whose cache fits is read once. This is
            the budget of a run while it computes the cache and trains; re-segmenting a saved
            run holds no view (:func:`dcseg.io.run_output.load_run`).
        half_weights: store the weights as float16 (3 significant digits; contributions
            below ``min_weight`` = 1e-3 are dropped anyway): the cache takes ~30 % less disk
            and memory; off stores float32.
    """

    min_weight: float = 1e-3
    max_per_pixel: int = 32
    memory_mb: int = 2048
    half_weights: bool = True


@dataclass(frozen=True)
class FrameBudget:
    """The working resolution and the frames a run trains on, chosen from the capture's size.

    :func:`dcseg.io.captures.plan.plan_capture` turns a budget and a capture's listing into a
    :class:`~dcseg.io.captures.plan.CapturePlan`. Outputs (per-view masks and labels) are still
    written at the capture's resolution.

    Attributes:
        max_side: frames are downscaled by the smallest integer factor that brings their
            longer side to at most this many pixels; None = native resolution.
        max_keyframes: at most this many keyframes, evenly spaced over those the pose rule keeps;
            None = every frame the pose rule keeps.
        min_translation: a frame is a keyframe when its camera moved at least this many metres
            since the last keyframe ...
        min_rotation_deg: ... or turned at least this many degrees. 0 and 0 keep every frame.
    """

    max_side: int | None = option(
        640,
        bounds=(MIN_WORKING_SIDE, MAX_SIDE),
        none_word="native",
        help="downscale by an integer factor until the longer side is at most this "
        f"(pixels, {MIN_WORKING_SIDE}-{MAX_SIDE}); 'native' = no downscaling",
        flag="--max-side",
    )
    max_keyframes: int | None = option(
        200,
        bounds=(1, MAX_KEYFRAMES),
        none_word="all",
        help=f"at most this many keyframes (1-{MAX_KEYFRAMES}); 'all' = no cap",
        flag="--max-keyframes",
    )
    min_translation: float = option(
        0.01, bounds=(0.0, 100.0), help="keyframe when the camera moved this far (m)"
    )
    min_rotation_deg: float = option(
        1.0, bounds=(0.0, 180.0), help="... or turned this many degrees"
    )

    def __post_init__(self) -> None:
        for name in ("max_side", "max_keyframes"):
            value = getattr(self, name)
            if value is not None and value < 1:
                raise ValueError(f"{name} must be >= 1 or None, got {value}")
        if not self.min_translation >= 0:
            raise ValueError(f"min_translation must be >= 0, got {self.min_translation}")
        if not 0 <= self.min_rotation_deg <= 180:
            raise ValueError(f"min_rotation_deg must be in [0, 180], got {self.min_rotation_deg}")


BUDGET_PRESETS: dict[str, FrameBudget] = {
    "fast": FrameBudget(),
    "paper": FrameBudget(max_side=1600, max_keyframes=1000),
}
"""The frame budget of each preset. ``fast`` trains a 1200x680 Replica capture at 600x340 and at
most 200 keyframes; ``paper`` keeps 1200x680 and ScanNet's 1296x968 native, at most 1000."""

NATIVE_BUDGET = FrameBudget(
    max_side=None, max_keyframes=None, min_translation=0.0, min_rotation_deg=0.0
)
"""Every frame at native resolution (what reading a capture without a budget gives)."""


DEFAULT_SCALE = 0.35
"""Default clustering scale (quantile space). The paper clusters at 0.8; on the 40-view
synthetic scenes that merges neighbouring objects grouped by SAM-style masks (a duck on its
tray): projection mIoU at 0.5 / 0.8 was clean 89.8 / 89.6, default noise 83.2 / 73.3, heavy
65.8 / 58.4. Between 0.25 / 0.35 / 0.5, as the mean over HDBSCAN sample seeds 0/10/20/30 on two
reconstructions of each scene: first clean 86.5 / 87.5 / 87.8, default 86.5 / 86.3 / 85.2,
heavy 62.1 / 63.8 / 61.2; second (the current fast preset) clean - / 89.2 / 89.0, default
- / 87.4 / 85.8, heavy - / 73.1 / 70.9. ``dcseg recluster`` changes it without retraining."""


@dataclass(frozen=True)
class PipelineConfig:
    """Every method parameter of a run; travels with a job and is stored in ``run.json``.

    Attributes:
        reconstruct, affinity, cluster, masks, assign, evaluate: each stage's own config.
        cache: the blending-weight cache truncation.
        budget: the working resolution and keyframes (:class:`FrameBudget`).
        rules: how the stage values follow the run's views, pixels and Gaussians
            (:mod:`dcseg.sizes`); the stage configs hold the values at the reference size.
        scale: the clustering scale in quantile space [0, 1] (:data:`DEFAULT_SCALE`; paper:
            0.8); re-clustering at another scale reuses everything trained.
        seed: the seed every stage's random choices derive from.
    """

    reconstruct: ReconstructConfig = field(default_factory=ReconstructConfig)
    affinity: AffinityConfig = field(default_factory=AffinityConfig)
    cluster: ClusterConfig = field(default_factory=ClusterConfig)
    masks: MaskConfig = field(default_factory=MaskConfig)
    assign: AssignConfig = field(default_factory=AssignConfig)
    evaluate: EvaluateConfig = field(default_factory=EvaluateConfig)
    cache: CacheConfig = field(default_factory=CacheConfig)
    budget: FrameBudget = field(default_factory=FrameBudget)
    rules: SizeRules = field(default_factory=SizeRules)
    scale: float = option(
        DEFAULT_SCALE,
        bounds=(0.0, 1.0),
        help="clustering scale in [0, 1]",
        flag="--scale",
        group="segment",
    )
    seed: int = option(
        0, bounds=(0, MAX_SEED), help="seed of every random choice", flag="--seed", group="segment"
    )

    def __post_init__(self) -> None:
        if not 0.0 <= self.scale <= 1.0:
            raise ValueError(f"scale must be in [0, 1] (quantile space), got {self.scale}")

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dict (see :meth:`from_dict`)."""
        return asdict(self)

    @classmethod
    def from_stored(cls, data: dict[str, Any]) -> tuple[PipelineConfig, list[str]]:
        """Rebuild a config stored by an earlier dcseg (``run.json``): keys of
        :data:`RETIRED_KEYS` are dropped (their stage's current behaviour applies) and listed
        as ``"stage.key"`` in the second value; any other unknown key raises ``ValueError``.
        """
        kept, dropped = renamed(data, RENAMED_KEYS), []
        for stage, retired in RETIRED_KEYS.items():
            section = kept.get(stage)
            if not isinstance(section, dict):
                continue
            gone = sorted(set(section) & set(retired))
            kept[stage] = {k: v for k, v in section.items() if k not in retired}
            dropped += [f"{stage}.{key}" for key in gone]
        return cls.from_dict(kept), dropped

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> PipelineConfig:
        """Rebuild from :meth:`to_dict` output; unknown keys raise ``ValueError``."""
        parts: dict[str, Any] = {}
        for f in fields(cls):
            if f.name not in data:
                continue
            value = data[f.name]
            stage = _STAGES.get(f.name)
            parts[f.name] = _build(stage, value, f.name) if stage else value
        unknown = sorted(set(data) - {f.name for f in fields(cls)})
        if unknown:
            raise ValueError(f"unknown pipeline config keys: {', '.join(unknown)}")
        return cls(**parts)

    def seeded(self, seed: int) -> PipelineConfig:
        """The same config with ``seed`` given to every stage."""
        return replace(
            self,
            seed=seed,
            reconstruct=replace(self.reconstruct, seed=seed),
            affinity=replace(self.affinity, seed=seed),
            cluster=replace(self.cluster, seed=seed),
        )


@dataclass(frozen=True)
class JobConfig:
    """The whole typed config of a job, as every stage receives it (:mod:`dcseg.stages`).

    Built from a preset and job options by the one builder, :func:`dcseg.options.build_config`
    (the CLI, the API and the worker all call it).

    Attributes:
        pipeline: every method parameter (:class:`PipelineConfig`).
        capture: how the capture is read (:class:`CaptureOptions`).
    """

    pipeline: PipelineConfig = field(default_factory=PipelineConfig)
    capture: CaptureOptions = field(default_factory=CaptureOptions)


def capture_options(value: Any) -> CaptureOptions:
    """:class:`CaptureOptions` from their JSON form (``run.json`` ``capture_options``, as
    ``asdict`` wrote it); unknown keys or bad values raise ``ValueError``."""
    options: CaptureOptions = _build(CaptureOptions, value, "capture")
    return options


def _build(stage: type[Any], value: Any, name: str) -> Any:
    if not isinstance(value, dict):
        raise ValueError(f"pipeline config {name!r} must be an object, got {type(value).__name__}")
    known = {f.name for f in fields(stage)}
    unknown = sorted(set(value) - known)
    if unknown:
        raise ValueError(f"unknown keys in pipeline config {name!r}: {', '.join(unknown)}")
    kwargs = {k: tuple(v) if isinstance(v, list) else v for k, v in value.items()}
    return stage(**kwargs)


RETIRED_KEYS: dict[str, dict[str, str]] = {
    "assign": {
        "min_class_share": "an absolute share floor, replaced by min_share_ratio",
        "stuff_min_fraction": "stuff regions are now one per connected surface",
        "min_contact_share": "a contact threshold tried and never released",
    },
}
"""Config fields earlier versions wrote to ``run.json`` and this one no longer has, per stage,
with what became of each: :meth:`PipelineConfig.from_stored` drops them so that re-clustering
and re-classifying older runs keep working. A field removed from a stage config is added here
in the same change."""


RENAMED_KEYS: dict[str, dict[str, str]] = {
    "budget": {"max_frames": "max_keyframes"},
    "assign": {"mode": "matcher", "maps_from": "label_maps"},
}
"""Config fields earlier versions wrote under another name, per section: old -> new.
:meth:`PipelineConfig.from_stored` (``run.json``) and :func:`dcseg.options.from_stored` (a
job's stored options) read them under the new name. Listed in ``CHANGELOG.md``."""


def renamed(data: Mapping[str, Any], renames: Mapping[str, Mapping[str, str]]) -> dict[str, Any]:
    """``data`` with the keys of each section renamed by ``renames`` (see
    :data:`RENAMED_KEYS`); a key already present under its new name wins."""
    out = dict(data)
    for section, names in renames.items():
        part = out.get(section)
        if isinstance(part, Mapping):
            moved = {names.get(k, k): v for k, v in part.items() if k in names}
            out[section] = {**moved, **{k: v for k, v in part.items() if k not in names}}
    return out


_STAGES: dict[str, type[Any]] = {
    "reconstruct": ReconstructConfig,
    "affinity": AffinityConfig,
    "cluster": ClusterConfig,
    "masks": MaskConfig,
    "assign": AssignConfig,
    "evaluate": EvaluateConfig,
    "cache": CacheConfig,
    "budget": FrameBudget,
    "rules": SizeRules,
}


def preset(name: str) -> PipelineConfig:
    """The named pipeline configuration: ``"fast"`` (CPU-friendly) or ``"paper"``."""
    if name not in ("fast", "paper"):
        raise ValueError(f"unknown preset {name!r}; choose fast or paper")
    return PipelineConfig(
        reconstruct=RECONSTRUCT_PRESETS[name],
        affinity=AFFINITY_PRESETS[name],
        budget=BUDGET_PRESETS[name],
        rules=RULE_PRESETS[name],
    )
