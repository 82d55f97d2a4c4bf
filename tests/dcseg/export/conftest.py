"""One finished run per test module, written in code (see :mod:`tests.scenes.runs`)."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.scenes.runs import make_run


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_run(tmp_path_factory.mktemp("export") / "run")
