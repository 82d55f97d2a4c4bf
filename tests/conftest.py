"""Test tiers: ``gpu`` tests skip without CUDA, ``slow`` tests need ``--runslow``."""

from __future__ import annotations

import os

import pytest

# Before torch or numba load: passive OpenMP waits keep their thread pools from fighting.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

# One SeaweedFS server for the whole session: a fixture imported into each test module would be
# one definition, and one server, per module. (Imported after the setting above.)
from tests.s3server import s3_server  # noqa: E402, F401 (fixture)


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--runslow", action="store_true", default=False, help="run slow tests")


def _cuda_available() -> bool:
    try:
        import torch
    except ImportError:  # pragma: no cover
        return False
    return bool(torch.cuda.is_available())


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    skip_gpu = pytest.mark.skip(reason="needs CUDA; no GPU on this machine")
    skip_slow = pytest.mark.skip(reason="slow; run with --runslow")
    has_cuda = _cuda_available() if any("gpu" in i.keywords for i in items) else False
    for item in items:
        if "gpu" in item.keywords and not has_cuda:
            item.add_marker(skip_gpu)
        if "slow" in item.keywords and not config.getoption("--runslow"):
            item.add_marker(skip_slow)
