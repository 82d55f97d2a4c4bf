"""Frozen data types shared by every stage: captures, 2D masks, vocabularies and ground truth.

Conventions (stated once, also in the README):

* Camera axes are OpenCV's: x right, y down, z forward. Poses are 4x4 camera-to-world matrices.
* Pixel (u, v) = (column, row); the centre of the top-left pixel is (0, 0).
* Depth is metric (metres), float32, 0 = invalid. Images are ``[H, W, 3]`` uint8 RGB.
* Label sentinel is ``-1`` (no class / no instance / noise) everywhere in memory.

Arrays inside these types are made read-only so that the dataclasses are frozen in earnest.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from dcseg.errors import InputError, Problem

RIGID_TOLERANCE = 1e-3
"""Largest deviation from orthonormality accepted in a pose's rotation block."""


def _frozen(array: NDArray[Any]) -> NDArray[Any]:
    array.flags.writeable = False
    return array


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics of an image of ``width`` x ``height`` pixels."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    def matrix(self) -> NDArray[np.float64]:
        """The 3x3 camera matrix K."""
        return np.array(
            [[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]], dtype=np.float64
        )

    def scaled(self, width: int, height: int) -> Intrinsics:
        """Intrinsics of the same camera resampled to ``width`` x ``height`` pixels.

        Uses the pixel-centre convention: ``c' = (c + 0.5) * s - 0.5``.
        """
        sx, sy = width / self.width, height / self.height
        return Intrinsics(
            fx=self.fx * sx,
            fy=self.fy * sy,
            cx=(self.cx + 0.5) * sx - 0.5,
            cy=(self.cy + 0.5) * sy - 0.5,
            width=width,
            height=height,
        )

    @classmethod
    def from_matrix(cls, k: NDArray[Any], width: int, height: int) -> Intrinsics:
        """Build from a 3x3 (or the top-left of a 4x4) camera matrix."""
        return cls(float(k[0, 0]), float(k[1, 1]), float(k[0, 2]), float(k[1, 2]), width, height)


LensModel = Literal["opencv", "fisheye"]
"""Lens distortion models, as OpenCV names and orders their coefficients: ``opencv`` =
``k1 k2 p1 p2 [k3 [k4 k5 k6]]`` (radial, tangential, rational radial), ``fisheye`` =
``k1 k2 k3 k4`` (equidistant with polynomial ``theta``)."""


@dataclass(frozen=True)
class Lens:
    """The lens distortion of a camera, as a layout states it.

    Attributes:
        model: :data:`LensModel`.
        coefficients: in the model's order (``opencv``: 4, 5 or 8; ``fisheye``: 4).
        source: where it was stated (a file and field), for messages and reports.
    """

    model: LensModel
    coefficients: tuple[float, ...]
    source: str = ""

    @property
    def is_identity(self) -> bool:
        """Whether the lens has no distortion (every coefficient 0)."""
        return not any(self.coefficients)


@dataclass(frozen=True)
class Undistortion:
    """How a frame with lens distortion was resampled onto a pinhole camera of its size.

    Attributes:
        lens: the distortion removed.
        source: the distorted camera's intrinsics (at the image's native size).
        pinhole: the intrinsics of the undistorted image (same size): the frame's.
    """

    lens: Lens
    source: Intrinsics
    pinhole: Intrinsics


def pose_problem(c2w: NDArray[Any]) -> str | None:
    """Why ``c2w`` is not a 4x4 rigid camera-to-world transform, or None if it is one."""
    if c2w.shape != (4, 4):
        return f"pose must be 4x4, got shape {tuple(c2w.shape)}"
    if not np.all(np.isfinite(c2w)):
        return "pose contains inf or NaN"
    if not np.allclose(c2w[3], [0.0, 0.0, 0.0, 1.0], atol=1e-6):
        return f"pose last row must be [0 0 0 1], got {np.round(c2w[3], 6).tolist()}"
    rot = c2w[:3, :3]
    err = float(np.abs(rot.T @ rot - np.eye(3)).max())
    if err > RIGID_TOLERANCE:
        return f"pose is not a rigid transform (rotation not orthonormal, error {err:.3g})"
    if np.linalg.det(rot) < 0:
        return "pose is not a rigid transform (rotation is a reflection, det < 0)"
    return None


@dataclass(frozen=True)
class Frame:
    """One posed RGB-D frame.

    Attributes:
        name: the frame's stem; 2D masks are matched to frames by this name.
        rgb: ``[H, W, 3]`` uint8 RGB.
        depth: ``[H, W]`` float32 metres, 0 = invalid.
        intrinsics: pinhole intrinsics for ``W`` x ``H``.
        c2w: ``[4, 4]`` float64 camera-to-world pose, OpenCV axes.
        files: where each part came from (``{"rgb": path, "depth": path, "pose": path}``), used
            to name files in error messages.
        undistortion: how the frame's files were resampled onto ``intrinsics`` when their
            camera has lens distortion (masks given for those files are resampled the same
            way, :mod:`dcseg.lens`); None = the files are the frame.
    """

    name: str
    rgb: NDArray[np.uint8]
    depth: NDArray[np.float32]
    intrinsics: Intrinsics
    c2w: NDArray[np.float64]
    files: dict[str, str] = field(default_factory=dict)
    undistortion: Undistortion | None = None

    def __post_init__(self) -> None:
        _frozen(self.rgb)
        _frozen(self.depth)
        _frozen(self.c2w)

    @property
    def height(self) -> int:
        return int(self.rgb.shape[0])

    @property
    def width(self) -> int:
        return int(self.rgb.shape[1])

    def file(self, part: str) -> str:
        """The file a part came from, or ``frame <name>`` when unknown."""
        return self.files.get(part, f"frame {self.name}")

    def problems(self) -> list[Problem]:
        """Everything wrong with this frame (empty when it is usable)."""
        out: list[Problem] = []
        if self.rgb.ndim != 3 or self.rgb.shape[2] != 3 or self.rgb.dtype != np.uint8:
            out.append(
                Problem(
                    self.file("rgb"),
                    f"colour must be HxWx3 uint8, got {self.rgb.shape} {self.rgb.dtype}",
                )
            )
            return out
        if self.depth.shape != self.rgb.shape[:2]:
            out.append(
                Problem(
                    self.file("depth"),
                    f"depth size {self.depth.shape[1]}x{self.depth.shape[0]} does not match "
                    f"colour size {self.width}x{self.height}",
                )
            )
        elif self.depth.dtype != np.float32:
            dtype_reason = f"depth must be float32, got {self.depth.dtype}"
            out.append(Problem(self.file("depth"), dtype_reason))
        elif not np.all(np.isfinite(self.depth)) or float(self.depth.min(initial=0.0)) < 0:
            out.append(Problem(self.file("depth"), "depth has negative or non-finite values"))
        k = self.intrinsics
        if (k.width, k.height) != (self.width, self.height):
            out.append(
                Problem(
                    self.file("intrinsics"),
                    f"intrinsics are for {k.width}x{k.height} but the image is "
                    f"{self.width}x{self.height}",
                )
            )
        if not (k.fx > 0 and k.fy > 0 and np.isfinite([k.fx, k.fy, k.cx, k.cy]).all()):
            out.append(Problem(self.file("intrinsics"), "focal lengths must be finite and > 0"))
        reason = pose_problem(self.c2w)
        if reason:
            out.append(Problem(self.file("pose"), reason))
        return out


DepthSource = Literal["sensor", "none", "rendered"]
"""Where a capture's depth comes from: ``"sensor"`` = the capture's own depth maps;
``"none"`` = an RGB-only capture (every frame's depth is all 0, i.e. missing everywhere);
``"rendered"`` = depth rendered from the reconstruction of an RGB-only capture, for the stages
after it (:func:`dcseg.reconstruct.rgbonly.with_rendered_depth`)."""


@dataclass(frozen=True)
class SparsePoints:
    """A structure-from-motion point cloud (COLMAP's ``points3D``), in the poses' world frame.

    Attributes:
        xyz: ``[P, 3]`` float64 positions (the model's units: arbitrary for SfM alone).
        rgb: ``[P, 3]`` uint8 colours.
        error: ``[P]`` float64 mean reprojection error (pixels).
        track: ``[P]`` int64 number of images observing each point.
        source: the file they were read from.
    """

    xyz: NDArray[np.float64]
    rgb: NDArray[np.uint8]
    error: NDArray[np.float64]
    track: NDArray[np.int64]
    source: str = ""

    def __post_init__(self) -> None:
        for array in (self.xyz, self.rgb, self.error, self.track):
            _frozen(array)

    def __len__(self) -> int:
        return int(self.xyz.shape[0])


@dataclass(frozen=True)
class Capture:
    """A validated sequence of posed RGB-D (or RGB-only) frames.

    Construction validates every frame and raises :class:`InputError` listing all problems.

    Attributes:
        frames: the frames, in capture order; names are unique.
        layout: which reader produced it (``"dcseg"``, ``"scannet"``, ``"replica"``,
            ``"nerfstudio"``, ``"7scenes"``).
        root: the folder the capture was read from.
        depth_source: where the frames' depth comes from (:data:`DepthSource`). With
            ``"none"`` every frame's depth is all 0 and the depth-dependent steps are off.
        sparse: the layout's sparse points when it has them (COLMAP ``points3D``); an RGB-only
            capture initialises its Gaussians from them.
    """

    frames: tuple[Frame, ...]
    layout: str
    root: str = ""
    depth_source: DepthSource = "sensor"
    sparse: SparsePoints | None = None

    def __post_init__(self) -> None:
        problems = capture_problems(self.frames, self.root or "capture")
        if self.depth_source == "none":
            problems += [
                Problem(f.file("depth"), "an RGB-only capture's depth must be all 0 (missing)")
                for f in self.frames
                if np.any(f.depth)
            ]
        if problems:
            raise InputError(problems)

    @property
    def has_depth(self) -> bool:
        """Whether the frames carry depth (measured or rendered), not all-0 placeholders."""
        return self.depth_source != "none"

    def __len__(self) -> int:
        return len(self.frames)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(f.name for f in self.frames)

    def frame(self, name: str) -> Frame:
        for f in self.frames:
            if f.name == name:
                return f
        raise KeyError(name)


def capture_problems(frames: tuple[Frame, ...], root: str) -> list[Problem]:
    """Every problem of a frame sequence: empty capture, duplicate names, bad frames."""
    if not frames:
        return [Problem(root, "capture is empty: no frames found")]
    out: list[Problem] = []
    seen: set[str] = set()
    for f in frames:
        if f.name in seen:
            out.append(Problem(f.file("rgb"), f"duplicate frame name {f.name!r}"))
        seen.add(f.name)
        out.extend(f.problems())
    return out


@dataclass(frozen=True)
class AgnosticMasks:
    """Class-agnostic 2D masks of one frame (SAM-style: overlapping, multi-granularity).

    Stored compactly as COCO run-length encodings (pycocotools), never as dense stacks.

    Attributes:
        name: the frame stem these masks belong to.
        height, width: the mask resolution.
        rles: one COCO RLE dict (``{"size": [H, W], "counts": bytes}``) per mask.
        source: the file the masks were read from (for error messages).
    """

    name: str
    height: int
    width: int
    rles: tuple[dict[str, Any], ...]
    source: str = ""

    def __len__(self) -> int:
        return len(self.rles)


@dataclass(frozen=True)
class SemanticMap:
    """A class-aware 2D segmentation of one frame: a per-pixel class index, -1 = unlabelled.

    Attributes:
        name: the frame stem.
        classes: ``[H, W]`` int32 index into the vocabulary, -1 = unlabelled.
        source: the file it was read from.
    """

    name: str
    classes: NDArray[np.int32]
    source: str = ""

    def __post_init__(self) -> None:
        _frozen(self.classes)


@dataclass(frozen=True)
class Vocabulary:
    """The class names that semantic maps and ground-truth labels index into."""

    names: tuple[str, ...]
    source: str = ""

    def __len__(self) -> int:
        return len(self.names)


@dataclass(frozen=True)
class GroundTruth:
    """Labelled 3D points for evaluation.

    Attributes:
        points: ``[N, 3]`` float64 world coordinates (same frame as the capture poses).
        labels: ``[N]`` int64 vocabulary index, -1 = ignored (out-of-range input becomes -1).
        instances: ``[N]`` int64 instance id, -1 = none; None when the file has no instances.
    """

    points: NDArray[np.float64]
    labels: NDArray[np.int64]
    instances: NDArray[np.int64] | None = None
    source: str = ""

    def __post_init__(self) -> None:
        _frozen(self.points)
        _frozen(self.labels)
        if self.instances is not None:
            _frozen(self.instances)
