"""``dcseg warmup``: every numba kernel is compiled (or loaded) by the tiny scene."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

import dcseg
from dcseg.cli import main
from dcseg.warmup import KERNEL_MODULES, helpers, kernel_dispatchers

WARM = {"compiled", "loaded", "in memory"}


def test_kernel_modules_lists_every_module_that_defines_a_kernel() -> None:
    root = Path(dcseg.__file__).parent
    defining = {
        ".".join(path.relative_to(root.parent).with_suffix("").parts)
        for path in root.rglob("*.py")
        # numba.njit directly or numba_projection's jit decorator
        if re.search(r"numba\.njit\(|^@jit\(", path.read_text(encoding="utf-8"), re.MULTILINE)
    }
    assert defining == set(KERNEL_MODULES)


def test_helpers_are_the_kernels_called_from_other_kernels() -> None:
    inner = helpers(kernel_dispatchers())
    assert "dcseg.render.numba_kernels._forward_tile" in inner
    assert "dcseg.cluster.components._find" in inner
    assert "dcseg.render.numba_kernels.forward" not in inner
    assert "dcseg.render.numba_kernels.bin_tiles" not in inner  # called from Python only


def test_warmup_compiles_every_kernel_and_lists_them(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["warmup"]) == 0
    out = capsys.readouterr().out
    lines = {line.split()[-3]: line for line in out.splitlines() if line.endswith("signatures)")}
    dispatchers = kernel_dispatchers()
    assert set(lines) == set(dispatchers)
    entry = set(dispatchers) - helpers(dispatchers)
    assert {"dcseg.render.numba_kernels.forward", "dcseg.export.tsdf._integrate"} <= entry
    for name in entry:
        status = lines[name].split("  ")[0].strip()
        assert status in WARM, lines[name]
        assert len(dispatchers[name].signatures) >= 1, name
    assert re.search(rf"^{len(dispatchers)} kernels in [0-9.]+ s: ", out, re.MULTILINE)
    assert "cache: " in out
