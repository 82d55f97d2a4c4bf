"""Camera pose refinement: a rigid correction per view, learned with the Gaussians.

Handheld captures come with poses from tracking (KinectFusion, ARKit, SLAM) that are off by a
fraction of a degree and a centimetre or two per frame; each view then pulls the Gaussians
towards its own misplaced copy of the scene and the fit blurs. A correction ``D = [R | t]`` per
view (rotation vector and translation in the camera's own axes, zero at the start) refines the
pose to ``c2w @ D``. Rendering the Gaussians moved by ``G = c2w D^-1 c2w^-1`` with the given
camera is rendering them with the refined camera, so the correction is fitted through the
Gaussians' means and rotations, which every renderer backend differentiates (none
differentiates through the camera). Camera axes keep the problem well conditioned: the
rotation turns the view about its own centre (the image shifts), the translation moves it
(parallax); a correction about the world origin would couple the two.

The corrections are fitted by their own Adam (one leaf per view, so a view's correction moves
only on the steps that see it); densification never touches them.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray
from torch import Tensor

from dcseg.gaussians import Gaussians
from dcseg.io.poses import CameraFile
from dcseg.reconstruct.stepping import AdamStepping
from dcseg.render import Camera
from dcseg.types import Capture

log = logging.getLogger(__name__)

_EPS = 1e-12


def rotvec_matrix(w: Tensor) -> Tensor:
    """``[3, 3]`` rotation of the rotation vector ``w`` (Rodrigues; differentiable at 0)."""
    theta = torch.sqrt((w * w).sum() + _EPS)
    zero = w.new_zeros(())
    k = torch.stack(
        [
            torch.stack([zero, -w[2], w[1]]),
            torch.stack([w[2], zero, -w[0]]),
            torch.stack([-w[1], w[0], zero]),
        ]
    )
    eye = torch.eye(3, dtype=w.dtype, device=w.device)
    return eye + torch.sin(theta) / theta * k + (1 - torch.cos(theta)) / (theta * theta) * (k @ k)


def rotvec_quat(w: Tensor) -> Tensor:
    """``[4]`` unit quaternion ``wxyz`` of the rotation vector ``w``."""
    theta = torch.sqrt((w * w).sum() + _EPS)
    return torch.cat([torch.cos(theta / 2).reshape(1), torch.sin(theta / 2) / theta * w])


def quat_multiply(a: Tensor, b: Tensor) -> Tensor:
    """The product ``a * b`` of quaternions ``wxyz`` (``[4]`` each)."""
    return quat_left(a) @ b


def quat_left(q: Tensor) -> Tensor:
    """``[4, 4]`` matrix ``L`` with ``q * p = L @ p`` for every quaternion ``p`` (``wxyz``)."""
    w, x, y, z = q.unbind(-1)
    return torch.stack(
        [
            torch.stack([w, -x, -y, -z]),
            torch.stack([x, w, -z, y]),
            torch.stack([y, z, w, -x]),
            torch.stack([z, -y, x, w]),
        ]
    )


def _matrix_quat(rot: NDArray[np.float64]) -> Tensor:
    """``[4]`` quaternion ``wxyz`` of a rotation matrix (constant, not differentiated)."""
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(rot).as_quat()
    return torch.tensor([w, x, y, z], dtype=torch.float64)


def move_gaussians(gaussians: Gaussians, delta: Tensor, camera: Camera) -> Gaussians:
    """The Gaussians moved by ``G = c2w D^-1 c2w^-1`` (``D`` the correction ``delta``:
    ``[6]`` rotation vector and translation in ``camera``'s axes), differentiable in
    ``delta``: rendered with ``camera`` they look as seen from its refined pose ``c2w @ D``."""
    c2w = camera.c2w.detach().double().cpu()
    rc, tc = c2w[:3, :3].to(delta.device), c2w[:3, 3].to(delta.device)
    rot_d = rotvec_matrix(delta[:3].double())
    # G = c2w D^-1 c2w^-1: rotation rc rot_d^T rc^T, translation from the three factors.
    rot = rc @ rot_d.T @ rc.T
    shift = tc - rot @ tc - rc @ rot_d.T @ delta[3:].double()
    dtype = gaussians.means.dtype
    means = gaussians.means @ rot.T.to(dtype) + shift.to(dtype)
    q_c = _matrix_quat(c2w[:3, :3].numpy()).to(delta.device)
    q_c_inverse = q_c * torch.tensor([1.0, -1.0, -1.0, -1.0], dtype=q_c.dtype, device=q_c.device)
    q_rot = quat_multiply(quat_multiply(q_c, rotvec_quat(-delta[:3].double())), q_c_inverse)
    # Every Gaussian's rotation turned by q_rot: one [N, 4] x [4, 4] product.
    quats = gaussians.quats @ quat_left(q_rot).T.to(gaussians.quats.dtype)
    return replace(gaussians, means=means, quats=quats)


def corrected_c2w(c2w: NDArray[np.float64], delta: Tensor) -> NDArray[np.float64]:
    """The refined pose ``c2w @ D`` of a view whose correction is ``delta``."""
    with torch.no_grad():
        d = np.eye(4)
        d[:3, :3] = rotvec_matrix(delta[:3].detach().double().cpu()).numpy()
        d[:3, 3] = delta[3:].detach().double().cpu().numpy()
    out: NDArray[np.float64] = np.asarray(c2w, dtype=np.float64) @ d
    return out


def corrected_camera(camera: Camera, delta: Tensor) -> Camera:
    """``camera`` at its refined pose (detached), for what reads the camera itself."""
    c2w = corrected_c2w(camera.c2w.detach().cpu().double().numpy(), delta)
    return replace(camera, c2w=torch.as_tensor(c2w, dtype=camera.c2w.dtype).to(camera.c2w))


@dataclass
class PoseCorrections(AdamStepping):
    """One learnable correction per view and the Adam that fits them.

    Attributes:
        deltas: per view a ``[6]`` leaf (rotation vector in radians, translation in metres).
        optimizer: Adam over the deltas; a view's delta moves only on steps that render it.
    """

    deltas: list[Tensor]
    optimizer: torch.optim.Adam

    @classmethod
    def zeros(cls, n_views: int, lr: float, device: torch.device | str) -> PoseCorrections:
        deltas = [torch.zeros(6, device=device, requires_grad=True) for _ in range(n_views)]
        return cls(deltas, torch.optim.Adam(deltas, lr=lr, eps=1e-15))


def pose_change(before: NDArray[np.float64], after: NDArray[np.float64]) -> tuple[float, float]:
    """``(degrees, metres)``: how far ``after`` turns and moves the camera of ``before``.

    The angle is ``atan2`` of the relative rotation's skew part over its trace part: exact for
    rotations, and for poses stored with slightly non-orthonormal rotations (KinectFusion's
    7-Scenes poses: 1.6e-4 off) it stays near their true angle where ``arccos`` of the trace
    alone would read a degree.

    Example:
        >>> turn = np.eye(4)
        >>> turn[:3, :3] = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]
        >>> [round(v, 6) for v in pose_change(np.eye(4), turn)]
        [90.0, 0.0]
        >>> skewed = np.diag([0.99984, 0.99984, 0.99984, 1.0])  # no turn at all
        >>> pose_change(skewed, np.eye(4))[0] < 0.01
        True
    """
    relative = after[:3, :3] @ before[:3, :3].T
    skew = np.array(
        [
            relative[2, 1] - relative[1, 2],
            relative[0, 2] - relative[2, 0],
            relative[1, 0] - relative[0, 1],
        ]
    )
    angle = np.arctan2(0.5 * np.linalg.norm(skew), 0.5 * (np.trace(relative) - 1.0))
    return float(np.degrees(angle)), float(np.linalg.norm(after[:3, 3] - before[:3, 3]))


def with_poses(capture: Capture, poses: Mapping[str, NDArray[np.float64]]) -> Capture:
    """``capture`` with the frames named in ``poses`` moved to those poses."""
    frames = tuple(
        replace(f, c2w=np.asarray(poses[f.name], dtype=np.float64)) if f.name in poses else f
        for f in capture.frames
    )
    return replace(capture, frames=frames)


def with_cameras(capture: Capture, cameras: CameraFile) -> Capture:
    """``capture`` seen by the cameras a reconstruction fitted (``poses.json``): each frame's
    depth registered onto its colour (:func:`dcseg.reconstruct.registration.registered_depth`),
    its pose from the file and its intrinsics corrected
    (:class:`dcseg.reconstruct.calibration.Correction`), each where the file has it."""
    from dcseg.reconstruct.calibration import Correction
    from dcseg.reconstruct.registration import Registration, registered_depth

    reg = None if cameras.registration is None else Registration.of_record(cameras.registration)
    fix = None if cameras.intrinsics is None else Correction.of_record(cameras.intrinsics)
    frames = []
    for frame in with_poses(capture, cameras.poses).frames:
        if reg is not None and not reg.identity:
            frame = replace(frame, depth=registered_depth(frame, reg))
        if fix is not None:
            frame = replace(frame, intrinsics=fix.apply(frame.intrinsics))
        frames.append(frame)
    if fix is not None and any(fix.replaces(f.intrinsics) for f in capture.frames):
        log.warning(
            "the scene's cameras were corrected from intrinsics fx fy cx cy %s at %dx%d; the "
            "capture now states others: the scene's corrected cameras are used",
            " ".join(f"{v:g}" for v in fix.given or ()), *fix.size,
        )  # fmt: skip
    return replace(capture, frames=tuple(frames))


def change_stats(
    before: Mapping[str, NDArray[np.float64]], after: Mapping[str, NDArray[np.float64]]
) -> dict[str, dict[str, float]]:
    """Median and largest rotation (degrees) and translation (metres) from ``before`` to
    ``after``, over the frames of ``after``."""
    changes = [pose_change(before[name], after[name]) for name in after]
    degrees, metres = (np.array(values) for values in zip(*changes, strict=True))
    return {
        "rotation_deg": {"median": float(np.median(degrees)), "max": float(degrees.max())},
        "translation_m": {"median": float(np.median(metres)), "max": float(metres.max())},
    }


def refinement_report(
    before: Mapping[str, NDArray[np.float64]], after: Mapping[str, NDArray[np.float64]]
) -> dict[str, Any]:
    """:func:`change_stats` and every refined pose (row-major)."""
    poses = {name: np.asarray(c2w).tolist() for name, c2w in after.items()}
    return {**change_stats(before, after), "poses": poses}
