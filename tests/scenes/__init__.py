"""Scenes built in code for the tests, one place for each: import the module you need.

* :mod:`tests.scenes.gaussians`: Gaussians and cameras (random scenes, discs and walls).
* :mod:`tests.scenes.blends`: blending weights (random, or listed pixel by pixel).
* :mod:`tests.scenes.affinity`: three objects seen in a few views, with masks and weights.
"""
