"""The independent readers of ``tools/export-check`` (npm, installed by ``scripts/setup.sh``):
the Khronos glTF validator, PlayCanvas splat-transform and the PlayCanvas engine's glTF parser;
found or the test skips saying why."""

from __future__ import annotations

import csv
import json
import shutil
import subprocess
from pathlib import Path
from typing import Any

import numpy as np
import pytest

TOOLS = Path(__file__).resolve().parents[3] / "tools" / "export-check"


def _node() -> str:
    node = shutil.which("node")
    if node is None:
        pytest.skip("node is not installed: the independent export readers cannot run")
    return node


def _installed(package: str) -> Path:
    folder = TOOLS / "node_modules" / package
    if not folder.is_dir():
        pytest.skip(f"{package} is not installed: run scripts/setup.sh (npm ci in {TOOLS})")
    return folder


def splat_transform(path: Path, out: Path) -> None:
    """Convert ``path`` to ``out`` (formats by extension) with PlayCanvas splat-transform."""
    folder = _installed("@playcanvas/splat-transform")
    cli = json.loads((folder / "package.json").read_text())["bin"]
    script = folder / (cli if isinstance(cli, str) else next(iter(cli.values())))
    subprocess.run([_node(), str(script), "-q", "-w", str(path), str(out)], check=True,
                   capture_output=True, timeout=300)  # fmt: skip


def splat_table_csv(path: Path, out: Path) -> dict[str, np.ndarray]:
    """``path`` (.spz, .ply ...) read by PlayCanvas splat-transform, written as CSV: columns."""
    splat_transform(path, out)
    with out.open(newline="") as f:
        rows = list(csv.reader(f))
    values = np.asarray(rows[1:], dtype=np.float64)
    return {name: values[:, i] for i, name in enumerate(rows[0])}


def gltf_validate(*paths: Path) -> list[dict[str, Any]]:
    """The Khronos glTF validator's report of each file."""
    _installed("gltf-validator")
    result = subprocess.run(
        [_node(), str(TOOLS / "validate-gltf.mjs"), *map(str, paths)],
        check=True, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    reports: list[dict[str, Any]] = json.loads(result.stdout)
    return reports


def playcanvas_glb(*paths: Path) -> list[dict[str, Any]]:
    """Each GLB as the PlayCanvas engine's glTF parser loads it (``read-glb-splats.mjs``): its
    nodes, each with the Gaussians the engine decoded from its mesh."""
    _installed("playcanvas")
    result = subprocess.run(
        [_node(), str(TOOLS / "read-glb-splats.mjs"), *map(str, paths)],
        check=True, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    files: list[dict[str, Any]] = json.loads(result.stdout)
    return files
