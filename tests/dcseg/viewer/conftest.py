"""Fixtures of the viewer tests: the labelled scene and a headless Chromium."""

from __future__ import annotations

import pytest

from tests.dcseg.viewer.browser import browser as browser
from tests.scenes.labelled import LabelledRun, write_labelled_run


@pytest.fixture(scope="session")
def labelled_run(tmp_path_factory: pytest.TempPathFactory) -> LabelledRun:
    return write_labelled_run(tmp_path_factory.mktemp("viewer") / "run")
