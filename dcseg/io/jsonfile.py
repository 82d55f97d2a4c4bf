"""Strict JSON files (NaN and infinity written as null, so every client can parse them)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np


def write_json(path: Path, body: Any) -> None:
    """Write JSON with NaN/inf as null (strict JSON for every client)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    text = json.dumps(_finite(body), indent=1, allow_nan=False)
    path.write_text(text + "\n", encoding="utf-8")


def _finite(value: Any) -> Any:
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {str(k): _finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(v) for v in value]
    if isinstance(value, np.generic):
        return _finite(value.item())
    return value
