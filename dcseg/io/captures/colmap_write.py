"""Write a capture as an RGB-only COLMAP model (``images/`` + binary ``sparse/0``), no depth.

What a 3DGS / SAGA / Gaussian Grouping user has after ``colmap mapper`` and
``image_undistorter``: undistorted images, PINHOLE cameras, world-to-camera poses and a sparse
point cloud. The tests and ``benchmarks/bench_rgbonly.py`` make one from a ``dcseg synth`` scene
with :func:`sample_sparse_points`, which stands in for structure from motion: points on the
observed surfaces, each seen by a few frames, with depth noise growing with distance. Byte
layouts as :mod:`.colmap` reads them (COLMAP's ``read_write_model.py``).
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from dcseg.io.images import write_image
from dcseg.types import Capture, SparsePoints

__all__ = ["sample_sparse_points", "write_colmap_rgb_only"]

_PINHOLE = 1


def sample_sparse_points(
    capture: Capture, count: int, noise: float = 0.01, seed: int = 0
) -> SparsePoints:
    """``count`` points back-projected from random valid depth pixels of random frames.

    Args:
        capture: a capture with depth (e.g. a ``dcseg synth`` scene).
        count: how many points (spread evenly over the frames).
        noise: standard deviation of the depth error relative to depth (0.01 = 1 cm at 1 m),
            as triangulation gives; the point moves along its ray.
        seed: the random seed.
    """
    rng = np.random.default_rng(seed)
    per_frame = -(-count // len(capture))
    xyz, rgb = [], []
    for frame in capture.frames:
        rows, cols = np.nonzero(frame.depth > 0)
        pick = rng.choice(len(rows), size=min(per_frame, len(rows)), replace=False)
        v, u = rows[pick], cols[pick]
        z = frame.depth[v, u].astype(np.float64) * (1.0 + noise * rng.standard_normal(len(v)))
        k = frame.intrinsics
        cam = np.stack([(u - k.cx) / k.fx * z, (v - k.cy) / k.fy * z, z], axis=1)
        xyz.append(cam @ frame.c2w[:3, :3].T + frame.c2w[:3, 3])
        rgb.append(frame.rgb[v, u])
    points = np.concatenate(xyz)[:count]
    n = len(points)
    return SparsePoints(
        xyz=points,
        rgb=np.concatenate(rgb)[:count].astype(np.uint8),
        error=np.full(n, 0.5),
        track=np.full(n, 2, np.int64),
    )


def write_colmap_rgb_only(capture: Capture, points: SparsePoints, root: Path) -> Path:
    """``images/<name>.png`` and a binary ``sparse/0`` model of ``capture`` (no ``depth/``).

    One PINHOLE camera per frame (COLMAP's principal point is dcseg's + 0.5); each point's track
    names its first two images (2D point index 0), which the reader only counts.
    """
    folder = root / "sparse" / "0"
    folder.mkdir(parents=True, exist_ok=True)
    cameras = struct.pack("<Q", len(capture))
    images = struct.pack("<Q", len(capture))
    for i, frame in enumerate(capture.frames, start=1):
        write_image(root / "images" / f"{frame.name}.png", frame.rgb)
        k = frame.intrinsics
        cameras += struct.pack("<iiQQ", i, _PINHOLE, k.width, k.height)
        cameras += struct.pack("<4d", k.fx, k.fy, k.cx + 0.5, k.cy + 0.5)
        w2c = np.linalg.inv(frame.c2w)
        qx, qy, qz, qw = Rotation.from_matrix(w2c[:3, :3]).as_quat()
        images += struct.pack("<i7di", i, qw, qx, qy, qz, *w2c[:3, 3], i)
        images += f"{frame.name}.png".encode() + b"\x00" + struct.pack("<Q", 0)
    (folder / "cameras.bin").write_bytes(cameras)
    (folder / "images.bin").write_bytes(images)
    out = [struct.pack("<Q", len(points))]
    track = struct.pack("<Q", 2) + struct.pack("<iiii", 1, 0, min(2, len(capture)), 0)
    for pid in range(len(points)):
        x, y, z = (float(v) for v in points.xyz[pid])
        r, g, b = (int(c) for c in points.rgb[pid])
        out.append(struct.pack("<QdddBBBd", pid + 1, x, y, z, r, g, b, float(points.error[pid])))
        out.append(track)
    (folder / "points3D.bin").write_bytes(b"".join(out))
    return root
