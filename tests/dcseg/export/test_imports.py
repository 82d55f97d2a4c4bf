"""The service image has no torch: the export package and its Gaussian formats (glb splats too)
must not need it."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

SCRIPT = """
import json, sys
from pathlib import Path
import dcseg.export
from dcseg.export import export_run
for fmt in ("ply", "spz", "splat", "glb"):
    export_run(Path(sys.argv[1]), Path(sys.argv[2]), fmt, instances=[1])
export_run(Path(sys.argv[1]), Path(sys.argv[2]) / "all", "ply")
print(json.dumps(sorted(m for m in sys.modules if m == "torch" or m.startswith("torch."))))
"""


def test_gaussian_exports_never_import_torch(run: Path, tmp_path: Path) -> None:
    result = subprocess.run(
        [sys.executable, "-c", SCRIPT, str(run), str(tmp_path)],
        capture_output=True,
        text=True,
        check=True,
        cwd=Path(__file__).resolve().parents[3],
    )
    assert json.loads(result.stdout.strip().splitlines()[-1]) == []
    assert (tmp_path / "instance_1.spz").is_file() and (tmp_path / "all" / "scene.ply").is_file()
