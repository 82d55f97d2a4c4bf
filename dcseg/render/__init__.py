"""Differentiable rendering of 3D Gaussians: one ``render`` function, three backends.

* ``reference``: pure PyTorch, tiled, autograd (the test oracle);
* ``cpu``: numba-compiled tile binning, forward and analytic backward (default on CPU);
* ``gsplat``: gsplat's CUDA kernels (default on CUDA when the ``[cuda]`` extra is installed).

``render_planar`` renders the same with each flat Gaussian's depth taken on its own plane.

Choose with the ``backend`` argument or the ``DCSEG_RENDER_BACKEND`` environment variable.
"""

from dcseg.render.api import render
from dcseg.render.backend import BACKEND_ENV, BACKENDS, select_backend
from dcseg.render.camera import Camera, RenderOutput
from dcseg.render.planar import render_planar

__all__ = [
    "BACKENDS",
    "BACKEND_ENV",
    "Camera",
    "RenderOutput",
    "render",
    "render_planar",
    "select_backend",
]
