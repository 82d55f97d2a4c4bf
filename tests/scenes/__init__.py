"""Scenes built in code for the tests, one place for each: import the module you need.

* :mod:`tests.scenes.gaussians`: Gaussians and cameras (random scenes, discs and walls).
"""
