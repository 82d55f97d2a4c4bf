"""The capture tests' fixture: a tiny RGB-D scene (see :mod:`tests.dcseg.io.layouts`)."""

from __future__ import annotations

import pytest

from tests.dcseg.io.layouts import RgbdScene, make_scene


@pytest.fixture
def rgbd_scene() -> RgbdScene:
    return make_scene()
