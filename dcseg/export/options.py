"""What an export writes: colours, SH degree, mesh resolution, where depth comes from."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from dcseg.errors import InputError

ColourMode = Literal["instance", "class"]
COLOUR_MODES: tuple[ColourMode, ...] = ("instance", "class")
MAX_SH_DEGREE = 3


@dataclass(frozen=True)
class ExportOptions:
    """Settings of :func:`dcseg.export.export_run` (the defaults suit phones and web viewers).

    Attributes:
        colour: ``"instance"`` or ``"class"`` paints every Gaussian (and mesh vertex) in its
            object's or class's palette colour (the colours of ``preview.png``); None keeps the
            reconstructed appearance.
        sh_degree: write exactly this SH degree (0-3): higher degrees are padded with zero
            coefficients (3 = the 45 ``f_rest_*`` the INRIA and SIBR loaders require), lower ones
            are truncated. None = 3 for PLY files (the INRIA layout; ``scene_labelled.ply``
            keeps the run's degree), the run's degree for the other formats.
        capture: the capture to read depth from when the run holds none (meshes only).
        voxel_size: TSDF voxel edge in metres; None = the longest side of the depth's bounding
            box / :attr:`voxels_per_side`.
        voxels_per_side: grid resolution along the longest side when ``voxel_size`` is None.
        max_faces: triangles kept per object mesh after decimation (mobile budget).
        spz_version: SPZ container version (3 = gzip, read by every SPZ loader; 4 = zstd).
    """

    colour: ColourMode | None = None
    sh_degree: int | None = None
    capture: Path | None = None
    voxel_size: float | None = None
    voxels_per_side: int = 256
    max_faces: int = 20_000
    spz_version: int = 3

    def __post_init__(self) -> None:
        """Raises InputError naming the field of a value out of range."""
        checks = {
            "colour": self.colour is None or self.colour in COLOUR_MODES,
            "sh_degree": self.sh_degree is None or 0 <= self.sh_degree <= MAX_SH_DEGREE,
            "voxel_size": self.voxel_size is None or self.voxel_size > 0,
            "voxels_per_side": 16 <= self.voxels_per_side <= 1024,
            "max_faces": self.max_faces >= 4,
            "spz_version": self.spz_version in (3, 4),
        }
        bad = [name for name, ok in checks.items() if not ok]
        if bad:
            raise InputError.single(bad[0], f"{getattr(self, bad[0])!r} is not {_RANGES[bad[0]]}")


_RANGES = {
    "colour": f"one of {', '.join(COLOUR_MODES)} or None",
    "sh_degree": f"an SH degree in [0, {MAX_SH_DEGREE}] or None",
    "voxel_size": "a positive length in metres or None",
    "voxels_per_side": "in [16, 1024]",
    "max_faces": "at least 4",
    "spz_version": "3 or 4",
}
