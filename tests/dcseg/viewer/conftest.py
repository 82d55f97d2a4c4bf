"""Fixtures of the viewer tests: the labelled scene and a headless Chromium."""

from __future__ import annotations

from tests.dcseg.viewer.browser import browser as browser
from tests.scenes.labelled import labelled_run as labelled_run
