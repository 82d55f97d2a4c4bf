"""``generate_scene``: render a seeded synthetic room into a capture, 2D masks and ground truth."""

from __future__ import annotations

import logging
import math
import tempfile
import time
from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dcseg.errors import InputError
from dcseg.reconstruct.registration import shifted
from dcseg.synth.agnostic import simulate_agnostic
from dcseg.synth.blur import MAX_BLUR_PX, blur_flow, motion_blur
from dcseg.synth.cameras import CameraModel, orbit_poses
from dcseg.synth.catalogue import VOCABULARY
from dcseg.synth.errors import (
    ERROR_MODELS,
    ErrorModel,
    SceneTruth,
    ViewOutput,
    ViewTruth,
    error_model,
)
from dcseg.synth.exposure import MAX_SPREAD, exposed, frame_gains
from dcseg.synth.failures import REALISTIC_VOCABULARY
from dcseg.synth.noise import NOISE_LEVELS, NoiseLevel, noisy_depth
from dcseg.synth.render import (
    Lighting,
    RenderedView,
    backproject,
    ground_truth_maps,
    instance_lookup,
    render_view,
)
from dcseg.synth.scene import SceneInstance, build_scene
from dcseg.synth.semantic import simulate_semantic
from dcseg.types import AgnosticMasks, Capture, Frame, GroundTruth, SemanticMap, Vocabulary

logger = logging.getLogger(__name__)

GT_VOXEL = 0.02
"""Voxel size (metres) of the ground-truth point cloud."""
CAMERA_RADII = (2.1, 1.6)
MAX_DEPTH_SHIFT = 16
"""Largest ``depth_shift_px`` component (pixels)."""
MAX_DISPARITY_STEP = 0.02
"""Coarsest disparity quantisation ``dcseg synth`` makes (1 / metres: 2 cm steps at 1 m, seven
times Kinect v1's)."""

# Independent random streams, so that changing one stage leaves the others' draws alone.
_SCENE, _CAMERA, _AGNOSTIC, _SEMANTIC, _DEPTH, _PARTS, _FATES, _POSE, _EXPOSURE, _BLUR = range(10)


@dataclass(frozen=True)
class SynthConfig:
    """What to generate.

    Attributes:
        seed: seeds every random choice (non-negative).
        frames: number of camera views.
        width, height: image size in pixels.
        noise: a name in :data:`~dcseg.synth.noise.NOISE_LEVELS`: ``clean``, ``default``,
            ``heavy`` (independent per-view errors) or ``realistic`` (consistent segmenter
            failures, :mod:`dcseg.synth.failures`; a larger vocabulary). Ground truth is
            always perfect.
        supersample: colour is rendered at this factor and area-averaged (anti-aliasing, like
            a camera integrating over its pixels); 1 = point-sampled, jagged edges that differ
            from view to view. Depth, masks and ground truth are never supersampled.
        depth_sigma: depth noise at 1 m (metres, grows with z squared) instead of the noise
            level's; None = the level's.
        disparity_step: depth quantised in disparity (:func:`dcseg.synth.noise.
            disparity_quantised`; 1 / metres, Kinect v1: 0.0029) after the noise; 0 = not.
        pose_error_deg, pose_error_m: the poses written into the capture are off by a
            rotation of this many degrees (standard deviation of the angle, random axis) and
            a translation of this standard deviation per axis; images, depth and ground truth
            come from the true poses. 0 = exact poses.
        motion_blur_px: colour is blurred by the camera moving during the exposure, towards
            the next pose of the trajectory (:mod:`dcseg.synth.blur`), with a median blur
            length of this many pixels; depth, masks and ground truth stay sharp (a depth
            sensor's own exposure is short). 0 = sharp.
        exposure_spread: auto exposure and white balance (:mod:`dcseg.synth.exposure`): every
            frame's colour times a per-channel gain that drifts smoothly along the trajectory,
            the log exposure gain with this standard deviation over the frames (0.2: about
            +-20 %); colour only. 0 = constant exposure.
        motion_blur_share: the share of views that are blurred (drawn at random, seeded);
            the others stay sharp, as in a handheld capture where only the fast turns smear
            the image. 1 = every view.
        depth_shift_px: colour/depth misregistration (separate depth and colour cameras,
            calibrated off): every depth map moved this many pixels right (``(dx, dy)``,
            negative = left / up) against the colour, the uncovered border without depth;
            masks and ground truth stay with the colour. ``(0, 0)`` = registered.
        error_model: a generator of :data:`~dcseg.synth.errors.ERROR_MODELS` makes the masks
            instead of the noise level (which then sets the depth noise only); "" = the
            level's own masks (``realistic`` for the ``realistic`` level).
    """

    seed: int = 0
    frames: int = 40
    width: int = 320
    height: int = 240
    noise: str = "default"
    supersample: int = 2
    depth_sigma: float | None = None
    disparity_step: float = 0.0
    pose_error_deg: float = 0.0
    pose_error_m: float = 0.0
    motion_blur_px: float = 0.0
    motion_blur_share: float = 1.0
    error_model: str = ""
    exposure_spread: float = 0.0
    depth_shift_px: tuple[int, int] = (0, 0)

    def __post_init__(self) -> None:
        if self.seed < 0:
            raise ValueError(f"seed must be >= 0, got {self.seed}")
        if self.frames < 1:
            raise ValueError(f"frames must be >= 1, got {self.frames}")
        if self.width < 8 or self.height < 8:
            raise ValueError(f"size must be at least 8x8, got {self.width}x{self.height}")
        if self.noise not in NOISE_LEVELS:
            raise ValueError(f"noise must be one of {sorted(NOISE_LEVELS)}, got {self.noise!r}")
        if not 1 <= self.supersample <= 4:
            raise ValueError(f"supersample must be between 1 and 4, got {self.supersample}")
        if self.depth_sigma is not None and not 0.0 <= self.depth_sigma <= 0.1:
            raise ValueError(f"depth_sigma must be between 0 and 0.1, got {self.depth_sigma}")
        if not 0.0 <= self.disparity_step <= MAX_DISPARITY_STEP:
            raise ValueError(
                f"disparity_step must be between 0 and {MAX_DISPARITY_STEP:g} per metre, "
                f"got {self.disparity_step}"
            )
        if not 0.0 <= self.pose_error_deg <= 10.0:
            raise ValueError(f"pose_error_deg must be between 0 and 10, got {self.pose_error_deg}")
        if not 0.0 <= self.pose_error_m <= 0.5:
            raise ValueError(f"pose_error_m must be between 0 and 0.5, got {self.pose_error_m}")
        if not 0.0 <= self.motion_blur_px <= MAX_BLUR_PX:
            raise ValueError(
                f"motion_blur_px must be between 0 and {MAX_BLUR_PX:g}, got {self.motion_blur_px}"
            )
        if not 0.0 <= self.exposure_spread <= MAX_SPREAD:
            raise ValueError(
                f"exposure_spread must be between 0 and {MAX_SPREAD:g}, got {self.exposure_spread}"
            )
        if not 0.0 <= self.motion_blur_share <= 1.0:
            raise ValueError(
                f"motion_blur_share must be between 0 and 1, got {self.motion_blur_share}"
            )
        if any(abs(v) > MAX_DEPTH_SHIFT for v in self.depth_shift_px):
            raise ValueError(
                f"depth_shift_px must be within +-{MAX_DEPTH_SHIFT} pixels, "
                f"got {self.depth_shift_px}"
            )
        if self.error_model and self.error_model not in ERROR_MODELS:
            raise ValueError(
                f"error_model must be one of {sorted(ERROR_MODELS)}, got {self.error_model!r}"
            )

    def segmenter(self) -> str | None:
        """The error generator that makes the masks, or None for the level's per-view noise."""
        if self.error_model:
            return self.error_model
        return "realistic" if NOISE_LEVELS[self.noise].failures is not None else None

    def level(self) -> NoiseLevel:
        """The noise level, with ``depth_sigma`` when it is set and ``disparity_step``."""
        level = replace(NOISE_LEVELS[self.noise], disparity_step=self.disparity_step)
        return level if self.depth_sigma is None else replace(level, depth_sigma=self.depth_sigma)

    def vocabulary(self) -> Vocabulary:
        """The class names: the error generators add look-alikes after the scene's classes."""
        return Vocabulary(VOCABULARY if self.segmenter() is None else REALISTIC_VOCABULARY)


@dataclass(frozen=True)
class SynthScene:
    """A generated scene, in memory.

    Attributes:
        config: what was asked for.
        vocabulary: the class names every label indexes into.
        instances: the instance table (ids 1..N).
        capture: posed RGB-D frames (depth carries the configured noise).
        agnostic: simulated class-agnostic masks, one entry per frame.
        semantic: simulated class maps, one entry per frame.
        gt_depth: per frame ``[H, W]`` float32 noise-free depth, 0 = nothing hit.
        gt_semantic: per frame ``[H, W]`` int32 class index, -1 = none.
        gt_instance: per frame ``[H, W]`` int32 instance id, -1 = none.
        ground_truth: labelled points on the visible surfaces (voxel-downsampled).
        timings: seconds spent per stage.
        mask_scores: per frame, one confidence per agnostic mask, or None where the error
            generator gives none.
    """

    config: SynthConfig
    vocabulary: Vocabulary
    instances: tuple[SceneInstance, ...]
    capture: Capture
    agnostic: tuple[AgnosticMasks, ...]
    semantic: tuple[SemanticMap, ...]
    gt_depth: tuple[NDArray[np.float32], ...]
    gt_semantic: tuple[NDArray[np.int32], ...]
    gt_instance: tuple[NDArray[np.int32], ...]
    ground_truth: GroundTruth
    timings: dict[str, float] = field(default_factory=dict)
    mask_scores: tuple[tuple[float, ...] | None, ...] = ()

    def __post_init__(self) -> None:
        for arrays in (self.gt_depth, self.gt_semantic, self.gt_instance):
            for array in arrays:
                array.flags.writeable = False


def _rng(cfg: SynthConfig, stream: int, index: int = 0) -> np.random.Generator:
    return np.random.default_rng([cfg.seed, stream, index])


def _import_pybullet() -> Any:
    try:
        import pybullet
    except ImportError:
        raise InputError.single(
            "pybullet", "dcseg synth needs pybullet: pip install 'dcseg[synth]'"
        ) from None
    return pybullet


def generate_scene(cfg: SynthConfig) -> SynthScene:
    """Build a seeded room, render ``cfg.frames`` views and simulate segmenter output.

    Args:
        cfg: seed, frame count, image size and noise level.

    Returns:
        The scene in memory; identical for identical ``cfg``.

    Raises:
        InputError: pybullet is not installed.

    Example:
        >>> scene = generate_scene(SynthConfig(seed=1, frames=6, width=80, height=60))
        >>> len(scene.capture)
        6
    """
    timings: dict[str, float] = {}
    start = time.perf_counter()
    camera = CameraModel(cfg.width, cfg.height)
    poses = true_poses(cfg)
    instances, views = _render_all(cfg, camera, poses, timings)
    tick = time.perf_counter()
    frames, extras = _simulate_frames(cfg, camera, poses, instances, views)
    timings["masks"] = time.perf_counter() - tick
    tick = time.perf_counter()
    gt = ground_truth_points(extras["depth"], extras["semantic"], extras["instance"], camera, poses)
    timings["ground_truth"] = time.perf_counter() - tick
    timings["total"] = time.perf_counter() - start
    logger.info(
        "generated %d frames, %d instances, %d GT points in %.1f s",
        cfg.frames,
        len(instances),
        len(gt.labels),
        timings["total"],
    )
    return SynthScene(
        config=cfg,
        vocabulary=cfg.vocabulary(),
        instances=tuple(instances),
        capture=Capture(tuple(frames), layout="dcseg", root="synth"),
        agnostic=tuple(extras["agnostic"]),
        semantic=tuple(extras["semantic_map"]),
        gt_depth=tuple(extras["depth"]),
        gt_semantic=tuple(extras["semantic"]),
        gt_instance=tuple(extras["instance"]),
        ground_truth=gt,
        timings=timings,
        mask_scores=tuple(extras["scores"]),
    )


def true_poses(cfg: SynthConfig) -> NDArray[np.float64]:
    """``[frames, 4, 4]`` the poses the views are rendered from (the capture's are these moved
    by ``pose_error_*``)."""
    return orbit_poses(cfg.frames, _rng(cfg, _CAMERA), np.zeros(3), CAMERA_RADII)


def exposure_gains(cfg: SynthConfig) -> NDArray[np.float64]:
    """``[frames, 3]`` every frame's R, G, B gain of ``cfg.exposure_spread``
    (:func:`dcseg.synth.exposure.frame_gains`; ones at 0)."""
    return frame_gains(cfg.frames, cfg.exposure_spread, _rng(cfg, _EXPOSURE))


def _render_all(
    cfg: SynthConfig, camera: CameraModel, poses: NDArray[np.float64], timings: dict[str, float]
) -> tuple[list[SceneInstance], list[RenderedView]]:
    """Build the room in a private DIRECT client and render every pose."""
    p = _import_pybullet()
    tick = time.perf_counter()
    client = int(p.connect(p.DIRECT))
    try:
        with tempfile.TemporaryDirectory(prefix="dcseg-synth-") as tmp:
            instances = build_scene(client, _rng(cfg, _SCENE), Path(tmp))
            timings["build"] = time.perf_counter() - tick
            tick = time.perf_counter()
            light = _lighting(_rng(cfg, _SCENE, 1))
            views = [render_view(client, camera, c2w, light, cfg.supersample) for c2w in poses]
            timings["render"] = time.perf_counter() - tick
    finally:
        p.disconnect(physicsClientId=client)
    return instances, views


def _lighting(rng: np.random.Generator) -> Lighting:
    angle = rng.uniform(0.0, 2.0 * math.pi)
    return Lighting((math.cos(angle), math.sin(angle), float(rng.uniform(1.5, 3.0))))


def _simulate_frames(
    cfg: SynthConfig,
    camera: CameraModel,
    poses: NDArray[np.float64],
    instances: list[SceneInstance],
    views: list[RenderedView],
) -> tuple[list[Frame], dict[str, list[Any]]]:
    """Frames with noisy depth, simulated masks and the per-frame ground truth."""
    from dcseg.io.masks import masks_from_dense

    level = cfg.level()
    by_id = {inst.id: inst for inst in instances}
    normals = _part_normals(cfg, instances)
    lookup = instance_lookup(instances)
    k = camera.intrinsics()
    maps = [ground_truth_maps(view.body, lookup) for view in views]
    segmenter = _Segmenter.start(cfg, by_id, normals, views, maps, poses, k.matrix())
    gains = exposure_gains(cfg)
    frames: list[Frame] = []
    extras: dict[str, list[Any]] = {
        key: [] for key in ("agnostic", "semantic_map", "depth", "semantic", "instance", "scores")
    }
    smeared = blurred_views(cfg)
    for i, (view, c2w, (inst_map, class_map)) in enumerate(zip(views, poses, maps, strict=True)):
        name = f"frame_{i:04d}"
        xyz = backproject(view.depth, k.matrix(), c2w)
        out = segmenter.view(cfg, i, ViewTruth(inst_map, class_map, xyz, view.depth))
        depth = shifted(noisy_depth(view.depth, level, _rng(cfg, _DEPTH, i)), cfg.depth_shift_px)
        pose = perturbed_pose(c2w, cfg.pose_error_deg, cfg.pose_error_m, _rng(cfg, _POSE, i))
        rgb = _blurred(cfg, view, k.matrix(), poses, i) if i in smeared else view.rgb
        rgb = exposed(rgb, gains[i])
        frames.append(Frame(name, rgb, depth, k, pose))
        extras["agnostic"].append(masks_from_dense(name, out.masks))
        extras["scores"].append(out.scores)
        extras["semantic_map"].append(SemanticMap(name, out.classes))
        extras["depth"].append(view.depth)
        extras["semantic"].append(class_map)
        extras["instance"].append(inst_map)
    return frames, extras


@dataclass(frozen=True)
class _Segmenter:
    """The simulated segmenter of a scene: an error generator with its drawn fates, or the
    noise level's per-view noise (``model`` None)."""

    scene: SceneTruth
    model: ErrorModel | None
    fates: Any

    @classmethod
    def start(
        cls,
        cfg: SynthConfig,
        by_id: dict[int, SceneInstance],
        normals: dict[int, NDArray[np.float64]],
        views: list[RenderedView],
        maps: list[tuple[NDArray[np.int32], NDArray[np.int32]]],
        poses: NDArray[np.float64],
        k: NDArray[np.float64],
    ) -> _Segmenter:
        name = cfg.segmenter()
        if name is None:
            return cls(SceneTruth(by_id, normals, {}), None, None)
        points = (
            (ids, backproject(view.depth, k, c2w))
            for view, (ids, _), c2w in zip(views, maps, poses, strict=True)
        )
        scene = SceneTruth(by_id, normals, instance_extents(points))
        model = error_model(name)
        return cls(scene, model, model.prepare(scene, _rng(cfg, _FATES)))

    def view(self, cfg: SynthConfig, i: int, truth: ViewTruth) -> ViewOutput:
        """View ``i``'s simulated class-agnostic masks and class map."""
        agnostic_rng, semantic_rng = _rng(cfg, _AGNOSTIC, i), _rng(cfg, _SEMANTIC, i)
        if self.model is None:
            ids, level, instances = truth.instance_map, cfg.level(), self.scene.instances
            normals = self.scene.part_normals
            dense = simulate_agnostic(ids, truth.xyz, instances, normals, level, agnostic_rng)
            classes = simulate_semantic(ids, truth.class_map, instances, level, semantic_rng)
            return ViewOutput(dense, classes)
        return self.model.view(truth, self.scene, self.fates, agnostic_rng, semantic_rng)


def instance_extents(
    views: Iterable[tuple[NDArray[np.int32], NDArray[np.float64]]], stride: int = 4
) -> dict[int, float]:
    """Per instance id, the diagonal (m) of the 5-95 % box of its points over all views
    (``(instance map, xyz)`` per view; every ``stride``-th pixel)."""
    kept = [(i[::stride, ::stride].ravel(), x[::stride, ::stride].reshape(-1, 3)) for i, x in views]
    ids = np.concatenate([i for i, _ in kept])
    xyz = np.concatenate([x for _, x in kept])
    out: dict[int, float] = {}
    for inst_id in (int(i) for i in np.unique(ids) if i >= 0):
        points = xyz[ids == inst_id]
        lo, hi = np.percentile(points, [5, 95], axis=0)
        out[inst_id] = float(np.linalg.norm(hi - lo))
    return out


def blurred_views(cfg: SynthConfig) -> frozenset[int]:
    """Indices of the views whose colour is blurred: all with ``motion_blur_share`` 1, else
    that share of them (rounded) drawn without replacement; none without blur."""
    if cfg.motion_blur_px == 0.0:
        return frozenset()
    if cfg.motion_blur_share >= 1.0:
        return frozenset(range(cfg.frames))
    count = round(cfg.motion_blur_share * cfg.frames)
    picked = _rng(cfg, _BLUR).choice(cfg.frames, size=count, replace=False)
    return frozenset(int(i) for i in picked)


def _blurred(
    cfg: SynthConfig, view: RenderedView, k: NDArray[np.float64], poses: NDArray[np.float64], i: int
) -> NDArray[np.uint8]:
    """View ``i``'s colour blurred towards its neighbour on the trajectory (the next pose;
    the previous one for the last view)."""
    if cfg.motion_blur_px == 0.0 or len(poses) < 2:
        return view.rgb
    other = poses[i + 1] if i + 1 < len(poses) else poses[i - 1]
    return motion_blur(view.rgb, blur_flow(view.depth, k, poses[i], other), cfg.motion_blur_px)


def perturbed_pose(
    c2w: NDArray[np.float64], error_deg: float, error_m: float, rng: np.random.Generator
) -> NDArray[np.float64]:
    """``c2w`` rotated about its camera centre by an angle ~ N(0, ``error_deg``) about a
    random axis and moved by N(0, ``error_m``) per axis (a copy; exact when both are 0)."""
    from scipy.spatial.transform import Rotation

    out = np.array(c2w, dtype=np.float64, copy=True)
    if error_deg > 0:
        axis = rng.normal(size=3)
        angle = np.deg2rad(rng.normal(0.0, error_deg))
        rotation = Rotation.from_rotvec(axis / np.linalg.norm(axis) * angle).as_matrix()
        out[:3, :3] = rotation @ out[:3, :3]
    if error_m > 0:
        out[:3, 3] += rng.normal(0.0, error_m, size=3)
    return out


def _part_normals(
    cfg: SynthConfig, instances: list[SceneInstance]
) -> dict[int, NDArray[np.float64]]:
    """A fixed random unit normal per instance, so part splits agree across views."""
    rng = _rng(cfg, _PARTS)
    out: dict[int, NDArray[np.float64]] = {}
    for inst in instances:
        n = rng.normal(size=3)
        out[inst.id] = n / np.linalg.norm(n)
    return out


def ground_truth_points(
    depths: list[NDArray[np.float32]],
    classes: list[NDArray[np.int32]],
    instance_maps: list[NDArray[np.int32]],
    camera: CameraModel,
    poses: NDArray[np.float64],
) -> GroundTruth:
    """Labelled points on every visible surface: back-projected GT depth, voxel-downsampled.

    Each voxel of :data:`GT_VOXEL` keeps its first point (in frame and pixel order) with that
    point's class and instance, so every point carries a valid label.
    """
    k = camera.intrinsics().matrix()
    points, labels, inst = [], [], []
    for depth, cls, ids, c2w in zip(depths, classes, instance_maps, poses, strict=True):
        valid = (depth > 0) & (cls >= 0)
        xyz = backproject(depth, k, c2w)[valid]
        keep = _voxel_first(xyz)
        points.append(xyz[keep])
        labels.append(cls[valid][keep])
        inst.append(ids[valid][keep])
    all_points = np.concatenate(points)
    keep = _voxel_first(all_points)
    return GroundTruth(
        points=all_points[keep],
        labels=np.concatenate(labels)[keep].astype(np.int64),
        instances=np.concatenate(inst)[keep].astype(np.int64),
        source="synth",
    )


def _voxel_first(points: NDArray[np.float64]) -> NDArray[np.int64]:
    """Sorted indices of the first point in each occupied voxel."""
    if len(points) == 0:
        return np.zeros(0, dtype=np.int64)
    keys = np.floor(points / GT_VOXEL).astype(np.int64)
    keys -= keys.min(axis=0)
    dims = keys.max(axis=0) + 1
    linear = (keys[:, 0] * dims[1] + keys[:, 1]) * dims[2] + keys[:, 2]
    _, first = np.unique(linear, return_index=True)
    return np.sort(first).astype(np.int64)
