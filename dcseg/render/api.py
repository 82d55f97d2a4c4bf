"""``render``: one differentiable Gaussian rasterizer with three interchangeable backends."""

from __future__ import annotations

from collections.abc import Callable

from torch import Tensor

from dcseg.gaussians import Gaussians
from dcseg.render.backend import select_backend
from dcseg.render.camera import Camera, RenderOutput
from dcseg.render.projection import Splats, project
from dcseg.render.torch_renderer import composite_reference

Compositor = Callable[[Splats, Tensor, int, int], Tensor]
"""``(splats, values [N, C], W, H) -> [H, W, C + 2]``: values, depth times alpha, alpha."""
Projector = Callable[[Gaussians, Camera], Splats]


def render(
    gaussians: Gaussians,
    values: Tensor,
    camera: Camera,
    *,
    background: Tensor | None = None,
    backend: str | None = None,
) -> RenderOutput:
    """Alpha-composite per-Gaussian values into one camera (3DGS EWA splatting).

    Differentiable with respect to ``values`` and the Gaussians' means, quats, log scales and
    opacity logits. ``gaussians.sh`` is not used: the caller computes colours (or features,
    one-hot ids, ...) and passes them as ``values``.

    Args:
        gaussians: N Gaussians.
        values: ``[N, C]`` values to composite, any C >= 1.
        camera: the camera (its tensors are cast to the Gaussians' device and dtype).
        background: optional ``[C]`` value added as ``background * (1 - alpha)``.
        backend: ``"reference"``, ``"cpu"`` or ``"gsplat"``; None means the
            ``DCSEG_RENDER_BACKEND`` variable, else ``cpu`` for CPU tensors and ``gsplat``
            (when importable, otherwise ``reference``) for CUDA tensors.

    Returns:
        ``values [H, W, C]``, ``alpha [H, W]`` and expected ``depth [H, W]`` (0 where alpha = 0).

    Example:
        >>> out = render(gaussians, gaussians.colors_dc(), Camera.from_frame(frame))
        >>> out.values.shape  # (H, W, 3)
    """
    _check_inputs(gaussians, values, background)
    name = select_backend(gaussians.device, backend)
    if name == "gsplat":  # pragma: no cover - needs CUDA and gsplat
        from dcseg.render.gsplat_renderer import render_gsplat

        image, alpha, depth = render_gsplat(gaussians, values, camera)
        return _with_background(RenderOutput(image, alpha, depth), background)
    return _with_background(_render_splats(gaussians, values, camera, name), background)


def _stages(name: str) -> tuple[Projector, Compositor]:
    """The projection and compositor of a backend: numba for ``cpu``, PyTorch otherwise."""
    if name == "cpu":
        from dcseg.render.cpu_projection import project_cpu
        from dcseg.render.cpu_renderer import composite_cpu

        return project_cpu, composite_cpu
    return project, composite_reference


def _render_splats(gaussians: Gaussians, values: Tensor, camera: Camera, name: str) -> RenderOutput:
    """Project, then composite values, depth and alpha in one pass."""
    projector, compositor = _stages(name)
    splats = projector(gaussians, camera)
    image = compositor(splats, values, camera.width, camera.height)
    channels = values.shape[1]
    alpha = image[..., channels + 1]
    depth = image[..., channels] / alpha.clamp_min(1e-10)
    return RenderOutput(image[..., :channels], alpha, depth)


def _with_background(out: RenderOutput, background: Tensor | None) -> RenderOutput:
    if background is None:
        return out
    bg = background.to(device=out.values.device, dtype=out.values.dtype)
    return RenderOutput(out.values + bg * (1.0 - out.alpha)[..., None], out.alpha, out.depth)


def _check_inputs(gaussians: Gaussians, values: Tensor, background: Tensor | None) -> None:
    n = len(gaussians)
    if values.ndim != 2 or values.shape[0] != n or values.shape[1] < 1:
        raise ValueError(f"values must have shape ({n}, C) with C >= 1, got {tuple(values.shape)}")
    if background is not None and tuple(background.shape) != (values.shape[1],):
        got = tuple(background.shape)
        raise ValueError(f"background must have shape ({values.shape[1]},), got {got}")
