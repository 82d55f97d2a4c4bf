"""Turning Gaussians into glTF's axes (+Y up, right-handed, metres): positions, rotations and the
view-dependent colour (SH) together, so a turned scene renders as the original did.

Used by the formats whose specification fixes the axes: SPZ stores RUB (x right, y up, z back:
glTF's axes), and ``KHR_gaussian_splatting`` recommends splats in glTF's axes because node
transforms rotate SH only where a renderer implements it. The turn is ``frame.json``'s
``to_gltf`` matrix (the run's estimated up to +Y; see :mod:`dcseg.export.frame`).

SH coefficients are rotated with the matrix that maps the real SH basis of the 3DGS reference
code (degrees 1-3, the signs of ``sh_utils.eval_sh``) under the rotation: fitted by least
squares on sample directions, exact because each band is closed under rotation.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from dcseg.export.depth import poses
from dcseg.export.frame import describe_frame
from dcseg.io.splat_table import SplatTable

C1 = 0.4886025119029199
C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792,
      0.5462742152960396)  # fmt: skip
C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
      -0.4570457994644658, 1.445305721320277, -0.5900435899266435)  # fmt: skip
_SAMPLES = 64


def gltf_frame(run: Path, capture: Path | None, applied_in: list[str]) -> dict[str, Any]:
    """``frame.json``'s body for ``run`` (poses from its state, else ``capture``)."""
    return describe_frame(poses(run, capture), applied_in)


def gltf_turn(run: Path, capture: Path | None) -> NDArray[np.float64]:
    """``[3, 3]`` rotation from the run's world to glTF's axes (``frame.json``'s matrix)."""
    frame = gltf_frame(run, capture, [])
    return np.asarray(frame["to_gltf"]["matrix"], np.float64)[:3, :3]


def sh_basis(dirs: NDArray[np.float64], degree: int) -> NDArray[np.float64]:
    """``[M, (degree + 1)^2]`` real SH basis of the 3DGS reference code at unit ``dirs``."""
    x, y, z = dirs[:, 0], dirs[:, 1], dirs[:, 2]
    xx, yy, zz = x * x, y * y, z * z
    cols: list[Any] = [np.full_like(x, 0.28209479177387814)]
    if degree >= 1:
        cols += [-C1 * y, C1 * z, -C1 * x]
    if degree >= 2:
        cols += [C2[0] * x * y, C2[1] * y * z, C2[2] * (2 * zz - xx - yy), C2[3] * x * z,
                 C2[4] * (xx - yy)]  # fmt: skip
    if degree >= 3:
        cols += [C3[0] * y * (3 * xx - yy), C3[1] * x * y * z, C3[2] * y * (4 * zz - xx - yy),
                 C3[3] * z * (2 * zz - 3 * xx - 3 * yy), C3[4] * x * (4 * zz - xx - yy),
                 C3[5] * z * (xx - yy), C3[6] * x * (xx - 3 * yy)]  # fmt: skip
    return np.stack(cols, axis=1)


def sh_rotation(rot: NDArray[np.float64], degree: int) -> NDArray[np.float64]:
    """``[K, K]`` matrix ``M`` such that coefficients ``M @ c`` seen from direction ``rot @ d``
    give the colour ``c`` gave from ``d``."""
    rng = np.random.default_rng(0)
    dirs = rng.normal(size=(_SAMPLES, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    before = sh_basis(dirs @ rot, degree)  # rows: rot.T @ d
    matrix, *_ = np.linalg.lstsq(sh_basis(dirs, degree), before, rcond=None)
    out: NDArray[np.float64] = np.where(np.abs(matrix) < 1e-9, 0.0, matrix)
    return out


def quat_multiply(a: NDArray[Any], b: NDArray[Any]) -> NDArray[np.float64]:
    """Hamilton products ``a * b`` of ``wxyz`` quaternions (broadcasting)."""
    aw, ax, ay, az = np.moveaxis(np.asarray(a, np.float64), -1, 0)
    bw, bx, by, bz = np.moveaxis(np.asarray(b, np.float64), -1, 0)
    return np.stack(
        [aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
         aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw],
        axis=-1,
    )  # fmt: skip


def matrix_to_quat(rot: NDArray[np.float64]) -> NDArray[np.float64]:
    """The unit ``wxyz`` quaternion of a proper rotation matrix."""
    x, y, z, w = Rotation.from_matrix(rot).as_quat()
    return np.array([w, x, y, z])


def turned(table: SplatTable, rot: NDArray[np.float64]) -> SplatTable:
    """``table`` rotated by ``rot`` about the origin: centres, orientations and SH."""
    if np.allclose(rot, np.eye(3)):
        return table
    degree = table.sh_degree
    sh = np.einsum("ij,njc->nic", sh_rotation(rot, degree), table.sh.astype(np.float64))
    quats = quat_multiply(matrix_to_quat(rot), table.quats)
    return SplatTable(
        means=(table.means.astype(np.float64) @ rot.T).astype(np.float32),
        quats=quats.astype(np.float32),
        log_scales=table.log_scales,
        opacity_logits=table.opacity_logits,
        sh=sh.astype(np.float32),
        ints=table.ints,
    )
