"""Benchmark results files: JSON objects of named entries that runs add to or replace."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any


def write_entry(out: Path, name: str, report: dict[str, Any]) -> None:
    """Store ``report`` as the entry ``name`` of the JSON results file ``out`` (kept entries
    of other names)."""
    results = json.loads(out.read_text()) if out.exists() else {}
    results[name] = report
    out.write_text(json.dumps(results, indent=1) + "\n")
