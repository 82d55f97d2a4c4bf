"""Scenes built in code for the tests, one place for each: import the module you need.

* :mod:`tests.scenes.analytic`: a box on a checkered floor, ray-cast into RGB-D views.
* :mod:`tests.scenes.gaussians`: Gaussians and cameras (random scenes, discs and walls).
* :mod:`tests.scenes.blends`: blending weights (random, or listed pixel by pixel).
* :mod:`tests.scenes.affinity`: three objects seen in a few views, with masks and weights.
* :mod:`tests.scenes.runs`: a finished run of the box-on-a-floor scene (labelled, with state).
* :mod:`tests.scenes.labelled`: the viewer's labelled run (a floor, a box, a ball, noise).
"""
