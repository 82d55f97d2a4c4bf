"""Differentiable rendering of 3D Gaussians: one ``render`` function, three backends.

* ``reference``: pure PyTorch, tiled, autograd (the test oracle);
* ``cpu``: numba-compiled tile binning, forward and analytic backward (default on CPU);
* ``gsplat``: gsplat's CUDA kernels (default on CUDA when the ``[cuda]`` extra is installed).

Choose with the ``backend`` argument or the ``DCSEG_RENDER_BACKEND`` environment variable.
"""

from dcseg.render.api import render
from dcseg.render.backend import BACKEND_ENV, BACKENDS, select_backend
from dcseg.render.camera import Camera, RenderOutput

__all__ = ["BACKENDS", "BACKEND_ENV", "Camera", "RenderOutput", "render", "select_backend"]
